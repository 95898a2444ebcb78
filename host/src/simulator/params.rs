//! Simulation parameters, with the CANARY defaults of Basden, Myers & Gendron
//! (2011) §2.3, and presets for the paper's Rayleigh and sodium LGS cases.
//!
//! Every field has a default, so a TOML file only names what it changes:
//!
//! ```toml
//! r0_m = 0.1
//! photons = 150.0
//! [source]
//! kind = "rayleigh"
//! gate_depth_m = 1000.0
//! ```

use serde::{Deserialize, Serialize};

use super::SimError;

/// Everything the Monte-Carlo Shack-Hartmann simulator needs. Angles are in
/// arcseconds, lengths in metres, signals in photo-electrons (= photons: unit
/// quantum efficiency) unless the name says counts (ADU).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimulationParams {
    /// Telescope diameter (m). With `subapertures_across` it gives the
    /// sub-aperture diameter `d` (CANARY: 4.2 m / 7 = 0.6 m).
    pub telescope_diameter_m: f64,
    /// Sub-apertures across the pupil (7).
    pub subapertures_across: u32,
    /// Detector pixels across one sub-aperture (16: a 16x16 image).
    pub pixels_per_subaperture: u32,
    /// Detector pixel scale, arcsec/pixel (0.22; the sodium preset uses
    /// 24"/16 = 1.5).
    pub pixel_scale_arcsec: f64,
    /// WFS wavelength (640 nm).
    pub wavelength_m: f64,
    /// Diameter to the first dark ring of the lenslet's diffraction-limited
    /// spot (Airy pattern), arcsec (0.7). A free parameter, as in the paper;
    /// see the module documentation for how it is realised.
    pub airy_diameter_arcsec: f64,
    /// Whether to add atmospheric turbulence (`false`: a static, diffraction
    /// limited spot, e.g. for the linearity study).
    pub turbulence: bool,
    /// Fried parameter at `r0_wavelength_m` (0.125 m at 500 nm; it scales as
    /// lambda^(6/5)).
    pub r0_m: f64,
    /// Wavelength at which `r0_m` is given (500 nm).
    pub r0_wavelength_m: f64,
    /// von Kármán outer scale (30 m). `inf` (TOML) gives Kolmogorov.
    pub outer_scale_m: f64,
    /// Detected photons per sub-aperture per frame (200): the noiseless image
    /// on the detector sums to this.
    pub photons: f64,
    /// Gaussian read noise, rms electrons (2).
    pub read_noise_e: f64,
    /// An EMCCD at high multiplication gain (`false`: none). The
    /// multiplication register turns `n` photo-electrons into a
    /// Gamma(`n`, gain)-distributed charge: divided by the gain, its mean is
    /// `n` and its variance `n` again, so the photon noise's variance is
    /// doubled (the excess noise factor sqrt(2) of the paper's §3.10
    /// camera); `read_noise_e` is then the effective read noise after the
    /// gain.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub em_excess_noise: bool,
    /// Background (counts) added to every pixel of the camera image before
    /// digitisation, without shot noise (50); calibration subtracts it
    /// ([`super::Simulator::calibration_background`]).
    pub background: f64,
    /// Error of the background subtraction (counts, 0): the camera's true
    /// background is `background + background_error`, calibration subtracts
    /// `background`, so a constant `background_error` remains.
    pub background_error: f64,
    /// Camera gain, electrons per count (1).
    pub gain_e_per_count: f64,
    /// Camera bit depth; counts are clamped to `0 ..= 2^bit_depth - 1` (16).
    pub bit_depth: u8,
    /// The guide star.
    pub source: Source,
    /// How the stated Airy diameter and the WFS wavelength are reconciled
    /// (the paper's 0.7" spot is not the 0.54" diffraction of a 0.6 m
    /// sub-aperture at 640 nm): see [`SpotModel`].
    pub spot_model: SpotModel,
    /// The telescope pupil as this sub-aperture sees it (`None`: fully lit,
    /// the paper's model). A partly lit sub-aperture's lenslet pupil is cut
    /// by the telescope's edge or central obscuration. The image is still
    /// normalised to `photons`: scale them by the lit fraction yourself.
    pub pupil: Option<SubaperturePupil>,
    /// Numerical sampling (automatic by default).
    pub sampling: Sampling,
}

/// How the spot's diffraction core and the seeing are modelled.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SpotModel {
    /// The paper's stated spot: diffraction of the sub-aperture at the
    /// effective wavelength `theta_Airy d / 2.44` that gives the stated Airy
    /// diameter (834 nm for 0.7" over 0.6 m), with the turbulence's phase at
    /// that wavelength (so the seeing blur is that of 834 nm, d/r0 = 2.6).
    #[default]
    EffectiveWavelength,
    /// Everything at the WFS wavelength: the Airy diameter is the
    /// diffraction of `d` at `wavelength_m` (0.54" at 640 nm; the stated
    /// `airy_diameter_arcsec` is ignored), the seeing that of `wavelength_m`.
    WfsWavelength,
    /// Diffraction and seeing at the WFS wavelength, plus a static Gaussian
    /// blur (lenslet and optics aberrations) that widens the diffraction core
    /// to the FWHM of the stated Airy spot: `FWHM_blur^2 = FWHM(stated)^2 -
    /// FWHM(diffraction)^2`, with an Airy FWHM of 0.4219 of its diameter.
    WfsWavelengthBlurred,
}

impl SpotModel {
    /// Command-line name.
    pub fn name(&self) -> &'static str {
        match self {
            SpotModel::EffectiveWavelength => "effective-wavelength",
            SpotModel::WfsWavelength => "wfs-wavelength",
            SpotModel::WfsWavelengthBlurred => "wfs-wavelength-blurred",
        }
    }

    /// Parses [`SpotModel::name`].
    pub fn parse(text: &str) -> Option<SpotModel> {
        [
            SpotModel::EffectiveWavelength,
            SpotModel::WfsWavelength,
            SpotModel::WfsWavelengthBlurred,
        ]
        .into_iter()
        .find(|m| m.name() == text)
    }
}

/// Where a sub-aperture sits in the telescope pupil: its lenslet pupil is
/// the part of its circle of diameter `d` inside the annulus between the
/// telescope diameter and the central obscuration.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SubaperturePupil {
    /// Sub-aperture centre from the pupil centre, `[x, y]` (m).
    pub centre_m: [f64; 2],
    /// Diameter of the central obscuration (m); 0 for none.
    pub obscuration_m: f64,
}

impl Default for SimulationParams {
    fn default() -> Self {
        Self {
            telescope_diameter_m: 4.2,
            subapertures_across: 7,
            pixels_per_subaperture: 16,
            pixel_scale_arcsec: 0.22,
            wavelength_m: 640e-9,
            airy_diameter_arcsec: 0.7,
            turbulence: true,
            r0_m: 0.125,
            r0_wavelength_m: 500e-9,
            outer_scale_m: 30.0,
            photons: 200.0,
            read_noise_e: 2.0,
            em_excess_noise: false,
            background: 50.0,
            background_error: 0.0,
            gain_e_per_count: 1.0,
            bit_depth: 16,
            source: Source::Ngs,
            spot_model: SpotModel::EffectiveWavelength,
            pupil: None,
            sampling: Sampling::default(),
        }
    }
}

/// The guide star seen by the sub-aperture. A laser guide star is elongated
/// along the direction `elongation_angle_deg` on the detector (0: along x,
/// the columns; 90: along y): radially away from the launch position, as
/// seen from the sub-aperture.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Source {
    /// A natural guide star: a point source.
    #[default]
    Ngs,
    /// A range-gated Rayleigh beacon (paper §3.6.1): backscatter uniform in
    /// altitude over the gate, launched from the pupil centre.
    Rayleigh {
        /// Altitude of the gate centre (20 km).
        altitude_m: f64,
        /// Range-gate depth: the light-transit distance (0, 500, 1000, 1500 m).
        gate_depth_m: f64,
        /// Distance of the sub-aperture centre from the launch axis in the
        /// pupil (1.8 m: the centre of an edge sub-aperture of a 4.2 m pupil
        /// with 7 sub-apertures of 0.6 m).
        launch_offset_m: f64,
        /// FWHM of the unelongated beacon (a Gaussian), arcsec (0.28).
        spot_fwhm_arcsec: f64,
        /// Direction of the elongation on the detector, degrees from +x
        /// towards +y (0).
        #[serde(default)]
        elongation_angle_deg: f64,
    },
    /// A sodium beacon with a double-Gaussian sodium profile (paper §3.6.2).
    Sodium {
        /// Altitude of the lower peak (90 km).
        lower_peak_altitude_m: f64,
        /// Separation `s` of the upper peak above the lower (0 to 14 km).
        separation_m: f64,
        /// Peak densities of the lower and upper layers (0.4, 0.6).
        peak_densities: [f64; 2],
        /// Half widths at half maximum of the two layers (3.5 km, 2 km).
        half_widths_m: [f64; 2],
        /// Distance of the sub-aperture from the launch telescope (21 m).
        launch_offset_m: f64,
        /// FWHM of the unelongated beacon (a Gaussian), arcsec (0.28).
        spot_fwhm_arcsec: f64,
        /// Direction of the elongation on the detector, degrees from +x
        /// towards +y (0).
        #[serde(default)]
        elongation_angle_deg: f64,
    },
}

impl Source {
    /// The unit vector `[cos, sin]` of the elongation direction on the
    /// detector (`[1, 0]` for a NGS).
    pub fn elongation_direction(&self) -> [f64; 2] {
        match *self {
            Source::Ngs => [1.0, 0.0],
            Source::Rayleigh {
                elongation_angle_deg,
                ..
            }
            | Source::Sodium {
                elongation_angle_deg,
                ..
            } => {
                let a = elongation_angle_deg.to_radians();
                [a.cos(), a.sin()]
            }
        }
    }

    /// The same source elongated along `angle_deg` (a NGS is unchanged).
    pub fn with_elongation_angle(mut self, angle_deg: f64) -> Self {
        match &mut self {
            Source::Ngs => {}
            Source::Rayleigh {
                elongation_angle_deg,
                ..
            }
            | Source::Sodium {
                elongation_angle_deg,
                ..
            } => *elongation_angle_deg = angle_deg,
        }
        self
    }

    /// The paper's Rayleigh case for one range-gate depth.
    pub fn rayleigh(gate_depth_m: f64) -> Self {
        Source::Rayleigh {
            altitude_m: 20e3,
            gate_depth_m,
            launch_offset_m: 1.8,
            spot_fwhm_arcsec: 0.28,
            elongation_angle_deg: 0.0,
        }
    }

    /// The paper's sodium case for one peak separation.
    pub fn sodium(separation_m: f64) -> Self {
        Source::Sodium {
            lower_peak_altitude_m: 90e3,
            separation_m,
            peak_densities: [0.4, 0.6],
            half_widths_m: [3.5e3, 2.0e3],
            launch_offset_m: 21.0,
            spot_fwhm_arcsec: 0.28,
            elongation_angle_deg: 0.0,
        }
    }
}

/// Numerical sampling. The defaults are chosen automatically from the optics
/// (see [`super::Geometry`]); change them only to trade accuracy for speed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Sampling {
    /// Fine samples per detector pixel (`q`). `None`: the smallest `q >= 2`
    /// that samples the spot at 1.1 times its Nyquist rate.
    pub oversampling: Option<u32>,
    /// Field of view of the computed image grid over the detector's field
    /// of view (2.0). Light beyond the detector field is dropped; light beyond
    /// the grid would wrap around, so keep this >= 1.5.
    pub fov_factor: f64,
    /// Least number of phase samples across the sub-aperture (24).
    pub min_pupil_samples: f64,
    /// Most phase samples across the sub-aperture (48): above it, the PSF is
    /// computed on a smaller field than the image grid and zero-padded.
    pub max_pupil_samples: f64,
    /// Side of the FFT phase screen over the sub-aperture diameter (4.0).
    pub screen_factor: f64,
    /// Subharmonic levels added to the FFT screen. `None`: enough that the
    /// lowest frequency is below 1/(5 L0) (at most 12 levels).
    pub subharmonic_levels: Option<u32>,
}

impl Default for Sampling {
    fn default() -> Self {
        Self {
            oversampling: None,
            fov_factor: 2.0,
            min_pupil_samples: 24.0,
            max_pupil_samples: 48.0,
            screen_factor: 4.0,
            subharmonic_levels: None,
        }
    }
}

impl SimulationParams {
    /// The paper's baseline (CANARY NGS): the same as `default()`.
    pub fn canary() -> Self {
        Self::default()
    }

    /// The paper's Rayleigh LGS case (§3.6.1) for a range-gate depth.
    pub fn canary_rayleigh(gate_depth_m: f64) -> Self {
        Self {
            source: Source::rayleigh(gate_depth_m),
            ..Self::default()
        }
    }

    /// The paper's sodium LGS case (§3.6.2) for a peak separation: a 24"
    /// field over 16 pixels (1.5"/pixel) and 1000 photons.
    pub fn sodium(separation_m: f64) -> Self {
        Self {
            pixel_scale_arcsec: 24.0 / 16.0,
            photons: 1000.0,
            source: Source::sodium(separation_m),
            ..Self::default()
        }
    }

    /// Sub-aperture diameter `d` (m).
    pub fn subaperture_diameter_m(&self) -> f64 {
        self.telescope_diameter_m / self.subapertures_across as f64
    }

    /// Airy diameter (to the first dark ring) of the sub-aperture's
    /// diffraction at the WFS wavelength, arcsec.
    pub fn diffraction_airy_diameter_arcsec(&self) -> f64 {
        super::optics::AIRY_DIAMETER_LAMBDA_OVER_D * self.wavelength_m
            / self.subaperture_diameter_m()
            * super::turbulence::ARCSEC_PER_RAD
    }

    /// Fried parameter at the WFS wavelength (r0 scales as lambda^(6/5)).
    pub fn r0_at_wavelength(&self, wavelength_m: f64) -> f64 {
        self.r0_m * (wavelength_m / self.r0_wavelength_m).powf(1.2)
    }

    /// Checks every parameter's range.
    pub fn validate(&self) -> Result<(), SimError> {
        fn pos(name: &str, v: f64) -> Result<(), SimError> {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(SimError::Invalid(format!(
                    "{name} must be positive and finite, got {v}"
                )))
            }
        }
        fn finite(name: &str, v: f64) -> Result<(), SimError> {
            if v.is_finite() {
                Ok(())
            } else {
                Err(SimError::Invalid(format!("{name} must be finite, got {v}")))
            }
        }
        fn nonneg(name: &str, v: f64) -> Result<(), SimError> {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(SimError::Invalid(format!(
                    "{name} must be >= 0 and finite, got {v}"
                )))
            }
        }
        pos("telescope_diameter_m", self.telescope_diameter_m)?;
        if self.subapertures_across == 0 {
            return Err(SimError::Invalid("subapertures_across must be >= 1".into()));
        }
        if !(2..=256).contains(&self.pixels_per_subaperture) {
            return Err(SimError::Invalid(format!(
                "pixels_per_subaperture must be 2..=256, got {}",
                self.pixels_per_subaperture
            )));
        }
        pos("pixel_scale_arcsec", self.pixel_scale_arcsec)?;
        pos("wavelength_m", self.wavelength_m)?;
        pos("airy_diameter_arcsec", self.airy_diameter_arcsec)?;
        pos("r0_m", self.r0_m)?;
        pos("r0_wavelength_m", self.r0_wavelength_m)?;
        if self.outer_scale_m.is_nan() || self.outer_scale_m <= 0.0 {
            return Err(SimError::Invalid(format!(
                "outer_scale_m must be positive (inf allowed), got {}",
                self.outer_scale_m
            )));
        }
        pos("photons", self.photons)?;
        nonneg("read_noise_e", self.read_noise_e)?;
        if !self.background.is_finite() || !self.background_error.is_finite() {
            return Err(SimError::Invalid("background must be finite".into()));
        }
        pos("gain_e_per_count", self.gain_e_per_count)?;
        if !(1..=16).contains(&self.bit_depth) {
            return Err(SimError::Invalid(format!(
                "bit_depth must be 1..=16, got {}",
                self.bit_depth
            )));
        }
        match &self.source {
            Source::Ngs => {}
            Source::Rayleigh {
                altitude_m,
                gate_depth_m,
                launch_offset_m,
                spot_fwhm_arcsec,
                elongation_angle_deg,
            } => {
                pos("rayleigh altitude_m", *altitude_m)?;
                nonneg("rayleigh gate_depth_m", *gate_depth_m)?;
                if *gate_depth_m >= 2.0 * altitude_m {
                    return Err(SimError::Invalid(
                        "gate_depth_m must be < 2 altitude_m".into(),
                    ));
                }
                nonneg("rayleigh launch_offset_m", *launch_offset_m)?;
                nonneg("rayleigh spot_fwhm_arcsec", *spot_fwhm_arcsec)?;
                finite("rayleigh elongation_angle_deg", *elongation_angle_deg)?;
            }
            Source::Sodium {
                lower_peak_altitude_m,
                separation_m,
                peak_densities,
                half_widths_m,
                launch_offset_m,
                spot_fwhm_arcsec,
                elongation_angle_deg,
            } => {
                pos("sodium lower_peak_altitude_m", *lower_peak_altitude_m)?;
                nonneg("sodium separation_m", *separation_m)?;
                nonneg("sodium peak_densities[0]", peak_densities[0])?;
                nonneg("sodium peak_densities[1]", peak_densities[1])?;
                pos(
                    "sodium peak_densities sum",
                    peak_densities[0] + peak_densities[1],
                )?;
                pos("sodium half_widths_m[0]", half_widths_m[0])?;
                pos("sodium half_widths_m[1]", half_widths_m[1])?;
                if lower_peak_altitude_m - 6.0 * half_widths_m[0] <= 0.0 {
                    return Err(SimError::Invalid("sodium layer reaches the ground".into()));
                }
                nonneg("sodium launch_offset_m", *launch_offset_m)?;
                nonneg("sodium spot_fwhm_arcsec", *spot_fwhm_arcsec)?;
                finite("sodium elongation_angle_deg", *elongation_angle_deg)?;
            }
        }
        if let Some(pupil) = &self.pupil {
            finite("pupil centre_m x", pupil.centre_m[0])?;
            finite("pupil centre_m y", pupil.centre_m[1])?;
            nonneg("pupil obscuration_m", pupil.obscuration_m)?;
            if pupil.obscuration_m >= self.telescope_diameter_m {
                return Err(SimError::Invalid(
                    "pupil obscuration_m must be below telescope_diameter_m".into(),
                ));
            }
        }
        if self.spot_model == SpotModel::WfsWavelengthBlurred
            && self.airy_diameter_arcsec < self.diffraction_airy_diameter_arcsec() * (1.0 - 1e-9)
        {
            return Err(SimError::Invalid(format!(
                "spot model wfs-wavelength-blurred: the stated Airy diameter {}\" is below the diffraction limit {:.3}\" at the WFS wavelength",
                self.airy_diameter_arcsec,
                self.diffraction_airy_diameter_arcsec()
            )));
        }
        let s = &self.sampling;
        if let Some(q) = s.oversampling {
            if !(1..=64).contains(&q) {
                return Err(SimError::Invalid(format!(
                    "oversampling must be 1..=64, got {q}"
                )));
            }
        }
        if !(s.fov_factor.is_finite() && s.fov_factor >= 1.0 && s.fov_factor <= 8.0) {
            return Err(SimError::Invalid(format!(
                "fov_factor must be in 1..=8, got {}",
                s.fov_factor
            )));
        }
        if !(s.min_pupil_samples >= 4.0
            && s.max_pupil_samples >= s.min_pupil_samples
            && s.max_pupil_samples <= 512.0)
        {
            return Err(SimError::Invalid(
                "need 4 <= min_pupil_samples <= max_pupil_samples <= 512".into(),
            ));
        }
        if !(s.screen_factor.is_finite() && s.screen_factor >= 1.0 && s.screen_factor <= 16.0) {
            return Err(SimError::Invalid(format!(
                "screen_factor must be in 1..=16, got {}",
                s.screen_factor
            )));
        }
        if let Some(l) = s.subharmonic_levels {
            if l > 20 {
                return Err(SimError::Invalid(format!(
                    "subharmonic_levels must be <= 20, got {l}"
                )));
            }
        }
        Ok(())
    }
}
