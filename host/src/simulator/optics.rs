//! Sampling geometry, the lenslet pupil, the laser guide star's elongation
//! profile and the transfer functions applied to the spot.

use std::f64::consts::PI;

use rayon::prelude::*;
use rustfft::num_complex::Complex;

use super::params::{SimulationParams, Source, SpotModel, SubaperturePupil};
use super::turbulence::ARCSEC_PER_RAD;
use super::SimError;

/// First zero of J1 over pi: the Airy first dark ring is at 1.21967 lambda/D,
/// so its diameter is `AIRY_DIAMETER_LAMBDA_OVER_D` lambda/D.
pub const AIRY_DIAMETER_LAMBDA_OVER_D: f64 = 2.0 * 3.831_705_970_207_512 / PI;

/// FWHM of a Gaussian over its sigma.
const FWHM_PER_SIGMA: f64 = 2.354_820_045_030_949;

/// Half width at half maximum of a Gaussian over its sigma.
pub const HWHM_PER_SIGMA: f64 = FWHM_PER_SIGMA / 2.0;

/// FWHM of an Airy pattern over its diameter to the first dark ring
/// (1.029 / 2.439).
pub const AIRY_FWHM_PER_DIAMETER: f64 = 1.028_993_969_962_188 / AIRY_DIAMETER_LAMBDA_OVER_D;

/// Numbers derived from [`SimulationParams`] that fix the numerical model.
/// See the module documentation for what they mean.
#[derive(Clone, Debug, PartialEq)]
pub struct Geometry {
    /// Sub-aperture diameter `d` (m).
    pub subaperture_diameter_m: f64,
    /// Fine samples per detector pixel, `q`.
    pub oversampling: usize,
    /// Fine sample, arcsec (pixel scale / q).
    pub fine_sample_arcsec: f64,
    /// Side of the computed image grid, detector pixels (>= the detector).
    pub image_grid_pixels: usize,
    /// FFT size of the image grid (`q * image_grid_pixels`).
    pub image_fft_size: usize,
    /// FFT size of the lenslet field (the PSF grid).
    pub psf_fft_size: usize,
    /// Samples across the lenslet pupil (a real number: the circular pupil is
    /// anti-aliased).
    pub pupil_samples: f64,
    /// Side of the pupil array (`ceil(pupil_samples)`).
    pub pupil_array: usize,
    /// Pupil (and phase screen) sample spacing in the sub-aperture (m).
    pub pupil_sample_m: f64,
    /// The wavelength at which a `d` aperture gives the requested Airy
    /// diameter; the turbulent phase is computed at it.
    pub effective_wavelength_m: f64,
    /// Airy diameter of the computed diffraction (arcsec): the stated one
    /// for [`SpotModel::EffectiveWavelength`], that of the WFS wavelength
    /// otherwise.
    pub diffraction_airy_arcsec: f64,
    /// FWHM of the static Gaussian optics blur (arcsec; only
    /// [`SpotModel::WfsWavelengthBlurred`]).
    pub optics_blur_fwhm_arcsec: f64,
    /// Fried parameter at the WFS wavelength (m).
    pub r0_wfs_m: f64,
    /// Fried parameter at the effective wavelength (m).
    pub r0_effective_m: f64,
    /// FFT size of the phase screen.
    pub screen_fft_size: usize,
    /// Subharmonic levels of the phase screen.
    pub subharmonic_levels: usize,
    /// Full angular length of the LGS elongation profile (arcsec; for a
    /// Rayleigh gate `b Delta / (H^2 - Delta^2/4)`; for sodium the +-6 sigma
    /// span of the layer); 0 for a NGS.
    pub elongation_extent_arcsec: f64,
    /// RMS of the LGS elongation profile (arcsec); 0 for a NGS.
    pub elongation_rms_arcsec: f64,
    /// Angular span holding 99.9% of the LGS elongation profile (arcsec);
    /// 0 for a NGS. The image grid is made large enough to hold it.
    pub elongation_span_arcsec: f64,
}

/// Smallest integer `>= n` whose prime factors are all 2, 3, 5 or 7.
pub(crate) fn nice_fft_size(n: usize) -> usize {
    let mut m = n.max(1);
    loop {
        let mut r = m;
        for p in [2, 3, 5, 7] {
            while r.is_multiple_of(p) {
                r /= p;
            }
        }
        if r == 1 {
            return m;
        }
        m += 1;
    }
}

/// The DFT index `k` of an `n`-point transform as a signed frequency.
pub(crate) fn signed_index(k: usize, n: usize) -> i64 {
    if k < n.div_ceil(2) {
        k as i64
    } else {
        k as i64 - n as i64
    }
}

/// How the PSF grid (`mp` samples, optical axis at index 0) maps onto the
/// image grid (`mi` samples, same sample size): for each image-grid index,
/// up to two PSF-grid samples and weights. Equal sizes: the identity. A
/// larger image grid zero-pads the PSF; a smaller one crops it (light beyond
/// is dropped). The edge sample of an even grid, which stands for both
/// `+-m/2`, is split or averaged so the mapping stays symmetric.
pub(crate) fn grid_map(mp: usize, mi: usize) -> Vec<[(usize, f64); 2]> {
    let idx = |s: i64| s.rem_euclid(mp as i64) as usize;
    (0..mi)
        .map(|k| {
            let s = signed_index(k, mi);
            let none = [(0, 0.0), (0, 0.0)];
            if mi == mp {
                [(k, 1.0), (0, 0.0)]
            } else if mi > mp {
                let h = mp as i64 / 2;
                if mp.is_multiple_of(2) && s.abs() == h {
                    [(idx(-h), 0.5), (0, 0.0)]
                } else if signed_index(idx(s), mp) == s {
                    [(idx(s), 1.0), (0, 0.0)]
                } else {
                    none
                }
            } else if mi.is_multiple_of(2) && s == -(mi as i64 / 2) {
                [(idx(s), 0.5), (idx(-s), 0.5)]
            } else {
                [(idx(s), 1.0), (0, 0.0)]
            }
        })
        .collect()
}

impl Geometry {
    pub(crate) fn new(p: &SimulationParams) -> Result<Self, SimError> {
        let d = p.subaperture_diameter_m();
        let pix = p.pixel_scale_arcsec;
        let airy = match p.spot_model {
            SpotModel::EffectiveWavelength => p.airy_diameter_arcsec,
            SpotModel::WfsWavelength | SpotModel::WfsWavelengthBlurred => {
                p.diffraction_airy_diameter_arcsec()
            }
        };
        let blur = match p.spot_model {
            SpotModel::WfsWavelengthBlurred => {
                let stated = AIRY_FWHM_PER_DIAMETER * p.airy_diameter_arcsec;
                let diffraction = AIRY_FWHM_PER_DIAMETER * airy;
                (stated * stated - diffraction * diffraction)
                    .max(0.0)
                    .sqrt()
            }
            _ => 0.0,
        };
        let profile = elongation_profile(&p.source);
        let span = profile.as_ref().map_or(0.0, |prof| prof.span(0.999));
        let s = &p.sampling;
        // Nyquist for the intensity: fine sample <= lambda_eff / (2 d)
        // = airy / (2 * 2.44).
        let q_nyquist = 2.0 * AIRY_DIAMETER_LAMBDA_OVER_D * pix / airy;
        let q = match s.oversampling {
            Some(q) => q as usize,
            None => ((1.1 * q_nyquist).ceil() as usize).max(2),
        };
        let npx = p.pixels_per_subaperture as usize;
        // The grid holds fov_factor detector fields, and at least the LGS
        // profile's span plus four core widths: elongated light beyond the
        // detector must land on the grid (where it is dropped, like a field
        // stop) rather than wrap around onto the detector.
        let needed_px = (span + 4.0 * (airy + blur + spot_fwhm(&p.source))) / pix;
        let lgs_margin = ((needed_px - npx as f64) / 2.0).max(0.0);
        let margin = ((((s.fov_factor - 1.0) * npx as f64) / 2.0).max(lgs_margin)).ceil() as usize;
        let n_img = npx + 2 * margin;
        let m_img = q * n_img;
        let delta_fine = pix / q as f64;
        // Pupil samples across d for a PSF FFT of size m.
        let pupil_for = |m: usize| AIRY_DIAMETER_LAMBDA_OVER_D * m as f64 * delta_fine / airy;
        let m_psf = if pupil_for(m_img) < s.min_pupil_samples {
            nice_fft_size(
                (s.min_pupil_samples * airy / (AIRY_DIAMETER_LAMBDA_OVER_D * delta_fine)).ceil()
                    as usize,
            )
        } else if pupil_for(m_img) > s.max_pupil_samples {
            nice_fft_size(
                (s.max_pupil_samples * airy / (AIRY_DIAMETER_LAMBDA_OVER_D * delta_fine)).floor()
                    as usize,
            )
        } else {
            m_img
        };
        let n_d = pupil_for(m_psf);
        let n_s = (n_d - 1e-9).ceil() as usize;
        if m_psf < 2 * n_s + 1 {
            return Err(SimError::Invalid(format!(
                "oversampling {q} is below the spot's Nyquist rate (need q >= {q_nyquist:.2})"
            )));
        }
        let delta_pupil = d / n_d;
        let lambda_eff = airy / ARCSEC_PER_RAD * d / AIRY_DIAMETER_LAMBDA_OVER_D;
        let g = nice_fft_size(((s.screen_factor * n_d).ceil() as usize).max(n_s).max(8));
        let levels = match s.subharmonic_levels {
            Some(l) => l as usize,
            None => {
                let l0 = p.outer_scale_m;
                let side = g as f64 * delta_pupil;
                let mut l = 0usize;
                while l < 12 && (!l0.is_finite() || side * 3f64.powi(l as i32) < 5.0 * l0) {
                    l += 1;
                }
                l
            }
        };
        let (extent, rms) = match profile {
            Some(prof) => {
                let lo = prof.angles.iter().cloned().fold(f64::INFINITY, f64::min);
                let hi = prof
                    .angles
                    .iter()
                    .cloned()
                    .fold(f64::NEG_INFINITY, f64::max);
                let rms = (prof
                    .angles
                    .iter()
                    .zip(&prof.weights)
                    .map(|(a, w)| w * a * a)
                    .sum::<f64>())
                .sqrt();
                let extent = match p.source {
                    Source::Rayleigh {
                        altitude_m,
                        gate_depth_m,
                        launch_offset_m,
                        ..
                    } => {
                        launch_offset_m * gate_depth_m
                            / (altitude_m * altitude_m - gate_depth_m * gate_depth_m / 4.0)
                            * ARCSEC_PER_RAD
                    }
                    _ => hi - lo,
                };
                (extent, rms)
            }
            None => (0.0, 0.0),
        };
        Ok(Self {
            subaperture_diameter_m: d,
            oversampling: q,
            fine_sample_arcsec: delta_fine,
            image_grid_pixels: n_img,
            image_fft_size: m_img,
            psf_fft_size: m_psf,
            pupil_samples: n_d,
            pupil_array: n_s,
            pupil_sample_m: delta_pupil,
            effective_wavelength_m: lambda_eff,
            diffraction_airy_arcsec: airy,
            optics_blur_fwhm_arcsec: blur,
            r0_wfs_m: p.r0_at_wavelength(p.wavelength_m),
            r0_effective_m: p.r0_at_wavelength(lambda_eff),
            screen_fft_size: g,
            subharmonic_levels: levels,
            elongation_extent_arcsec: extent,
            elongation_rms_arcsec: rms,
            elongation_span_arcsec: span,
        })
    }
}

/// The lenslet pupil of a sub-aperture that the telescope pupil cuts:
/// [`pupil_mask`] times the part of each sample inside the telescope's
/// annulus (diameter `telescope_m`, obscuration `pupil.obscuration_m`), the
/// sub-aperture's centre at `pupil.centre_m` from the telescope's axis, `d`
/// the sub-aperture diameter (m). 16x16 sub-samples per sample.
pub(crate) fn cut_pupil_mask(
    n_d: f64,
    n_s: usize,
    d: f64,
    telescope_m: f64,
    pupil: &SubaperturePupil,
) -> Vec<f64> {
    const SUB: usize = 16;
    let r = n_d / 2.0;
    let c = n_s as f64 / 2.0;
    let metres_per_sample = d / n_d;
    let (r_out, r_in) = (telescope_m / 2.0, pupil.obscuration_m / 2.0);
    let mut a = vec![0.0; n_s * n_s];
    for y in 0..n_s {
        for x in 0..n_s {
            let mut inside = 0usize;
            for i in 0..SUB {
                let px = x as f64 - c + (i as f64 + 0.5) / SUB as f64;
                for j in 0..SUB {
                    let py = y as f64 - c + (j as f64 + 0.5) / SUB as f64;
                    if px.hypot(py) > r {
                        continue;
                    }
                    let tx = pupil.centre_m[0] + px * metres_per_sample;
                    let ty = pupil.centre_m[1] + py * metres_per_sample;
                    let rho = tx.hypot(ty);
                    if rho <= r_out && rho >= r_in {
                        inside += 1;
                    }
                }
            }
            a[y * n_s + x] = inside as f64 / (SUB * SUB) as f64;
        }
    }
    a
}

/// The lenslet pupil: amplitude transmission of each `n_s x n_s` sample, the
/// fraction of the sample's square inside a circle of diameter `n_d`
/// samples centred on the array (16x16 sub-samples per edge sample).
pub(crate) fn pupil_mask(n_d: f64, n_s: usize) -> Vec<f64> {
    const SUB: usize = 16;
    let r = n_d / 2.0;
    let c = n_s as f64 / 2.0;
    let mut a = vec![0.0; n_s * n_s];
    for y in 0..n_s {
        for x in 0..n_s {
            let (x0, y0) = (x as f64 - c, y as f64 - c);
            // nearest and farthest corner distances
            let near_x = if x0 > 0.0 {
                x0
            } else if x0 + 1.0 < 0.0 {
                -(x0 + 1.0)
            } else {
                0.0
            };
            let near_y = if y0 > 0.0 {
                y0
            } else if y0 + 1.0 < 0.0 {
                -(y0 + 1.0)
            } else {
                0.0
            };
            let far_x = x0.abs().max((x0 + 1.0).abs());
            let far_y = y0.abs().max((y0 + 1.0).abs());
            a[y * n_s + x] = if far_x.hypot(far_y) <= r {
                1.0
            } else if near_x.hypot(near_y) >= r {
                0.0
            } else {
                let mut inside = 0usize;
                for i in 0..SUB {
                    let px = x0 + (i as f64 + 0.5) / SUB as f64;
                    for j in 0..SUB {
                        let py = y0 + (j as f64 + 0.5) / SUB as f64;
                        if px.hypot(py) <= r {
                            inside += 1;
                        }
                    }
                }
                inside as f64 / (SUB * SUB) as f64
            };
        }
    }
    a
}

/// An LGS elongation profile along x: angles (arcsec, centroid at 0; the
/// sub-aperture is at `+b` from the launch axis, so the beam at altitude `z`
/// is seen at `-b/z`) and normalised weights, from a fine sampling of
/// altitude. `None` for a NGS.
pub(crate) struct ElongationProfile {
    pub angles: Vec<f64>,
    pub weights: Vec<f64>,
}

impl ElongationProfile {
    /// The smallest angular interval holding `fraction` of the profile's
    /// light, trimming equal tails (arcsec).
    pub fn span(&self, fraction: f64) -> f64 {
        let mut pairs: Vec<(f64, f64)> = self
            .angles
            .iter()
            .copied()
            .zip(self.weights.iter().copied())
            .collect();
        pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
        let tail = (1.0 - fraction) / 2.0;
        let (mut acc, mut lo, mut hi) = (0.0, pairs[0].0, pairs[pairs.len() - 1].0);
        for &(a, w) in &pairs {
            acc += w;
            if acc >= tail {
                lo = a;
                break;
            }
        }
        acc = 0.0;
        for &(a, w) in pairs.iter().rev() {
            acc += w;
            if acc >= tail {
                hi = a;
                break;
            }
        }
        hi - lo
    }

    /// The profile binned on a grid of `step` arcsec (weights at the bins'
    /// light-weighted mean angles): a few hundred samples instead of
    /// thousands, for the 2-D transfer of a rotated elongation.
    fn binned(&self, step: f64) -> ElongationProfile {
        let lo = self.angles.iter().copied().fold(f64::INFINITY, f64::min);
        let mut sums: std::collections::BTreeMap<i64, (f64, f64)> = Default::default();
        for (&a, &w) in self.angles.iter().zip(&self.weights) {
            let e = sums.entry(((a - lo) / step).floor() as i64).or_default();
            e.0 += w * a;
            e.1 += w;
        }
        let (mut angles, mut weights) = (Vec::new(), Vec::new());
        for (_, (wa, w)) in sums {
            if w > 0.0 {
                angles.push(wa / w);
                weights.push(w);
            }
        }
        ElongationProfile { angles, weights }
    }
}

/// Relative return per unit altitude.
type AltitudeDensity = Box<dyn Fn(f64) -> f64>;

pub(crate) fn elongation_profile(source: &Source) -> Option<ElongationProfile> {
    let (b, z_lo, z_hi, n, density): (f64, f64, f64, usize, AltitudeDensity) = match *source {
        Source::Ngs => return None,
        Source::Rayleigh {
            altitude_m,
            gate_depth_m,
            launch_offset_m,
            ..
        } => (
            launch_offset_m,
            altitude_m - gate_depth_m / 2.0,
            altitude_m + gate_depth_m / 2.0,
            2048,
            Box::new(|_| 1.0),
        ),
        Source::Sodium {
            lower_peak_altitude_m,
            separation_m,
            peak_densities,
            half_widths_m,
            launch_offset_m,
            ..
        } => {
            let z1 = lower_peak_altitude_m;
            let z2 = z1 + separation_m;
            let s1 = half_widths_m[0] / HWHM_PER_SIGMA;
            let s2 = half_widths_m[1] / HWHM_PER_SIGMA;
            let [a1, a2] = peak_densities;
            (
                launch_offset_m,
                (z1 - 6.0 * s1).min(z2 - 6.0 * s2),
                (z1 + 6.0 * s1).max(z2 + 6.0 * s2),
                8192,
                Box::new(move |z: f64| {
                    a1 * (-0.5 * ((z - z1) / s1).powi(2)).exp()
                        + a2 * (-0.5 * ((z - z2) / s2).powi(2)).exp()
                }),
            )
        }
    };
    let mut angles = Vec::with_capacity(n);
    let mut weights = Vec::with_capacity(n);
    for i in 0..n {
        let z = z_lo + (z_hi - z_lo) * (i as f64 + 0.5) / n as f64;
        angles.push(-b / z * ARCSEC_PER_RAD);
        weights.push(density(z));
    }
    let total: f64 = weights.iter().sum();
    weights.iter_mut().for_each(|w| *w /= total);
    let mean: f64 = angles.iter().zip(&weights).map(|(a, w)| a * w).sum();
    angles.iter_mut().for_each(|a| *a -= mean);
    Some(ElongationProfile { angles, weights })
}

/// The unelongated LGS spot's FWHM (arcsec), 0 for a NGS.
fn spot_fwhm(source: &Source) -> f64 {
    match *source {
        Source::Ngs => 0.0,
        Source::Rayleigh {
            spot_fwhm_arcsec, ..
        }
        | Source::Sodium {
            spot_fwhm_arcsec, ..
        } => spot_fwhm_arcsec,
    }
}

/// Fourier transform of the elongation profile at `f` cycles/arcsec.
pub(crate) fn profile_transfer(prof: &ElongationProfile, f: f64) -> Complex<f64> {
    let mut s = Complex::new(0.0, 0.0);
    for (a, w) in prof.angles.iter().zip(&prof.weights) {
        let ph = -2.0 * PI * f * a;
        s += Complex::new(ph.cos(), ph.sin()) * w;
    }
    s
}

/// The transfer functions applied to the PSF's spectrum on the image grid
/// (DFT order, length `image_fft_size` per axis).
pub(crate) struct Transfers {
    /// Per axis: the pixel's box response (integration over the pixel,
    /// exact), the source's and optics' Gaussian blur, the shift that puts
    /// the fine grid's sample `0` (the optical axis) at the centre of the
    /// detector, between the two middle pixels, so the decimated samples are
    /// the pixel centres; for an elongation along x, also its profile (in
    /// `x`).
    pub x: Vec<Complex<f64>>,
    pub y: Vec<Complex<f64>>,
    /// A rotated elongation's transfer, `[ky][kx]` (not separable); `None`
    /// when the elongation is along x (in `x`) or there is none.
    pub rotated: Option<Vec<Complex<f64>>>,
}

/// The transfer functions of [`Transfers`]. The Nyquist bin of an even
/// transform is zeroed (the PSF has no power there) to keep the result real.
pub(crate) fn transfers(g: &Geometry, source: &Source) -> Transfers {
    let m = g.image_fft_size;
    let n_img = g.image_grid_pixels as f64;
    let fwhm = spot_fwhm(source).hypot(g.optics_blur_fwhm_arcsec);
    let sigma = fwhm / FWHM_PER_SIGMA;
    let prof = elongation_profile(source);
    let direction = source.elongation_direction();
    let along_x = direction == [1.0, 0.0];
    let freq = |k: usize| signed_index(k, m) as f64 / (m as f64 * g.fine_sample_arcsec);
    let nyquist = |k: usize| m.is_multiple_of(2) && signed_index(k, m) == -(m as i64 / 2);
    let mut tx = Vec::with_capacity(m);
    let mut ty = Vec::with_capacity(m);
    for k in 0..m {
        if nyquist(k) {
            tx.push(Complex::new(0.0, 0.0));
            ty.push(Complex::new(0.0, 0.0));
            continue;
        }
        let ks = signed_index(k, m) as f64;
        // pixel box: width q fine samples
        let arg = PI * ks / n_img;
        let pixel = if ks == 0.0 { 1.0 } else { arg.sin() / arg };
        // shift: evaluate at fine position -q (n_img - 1)/2 + q j
        let ph = -PI * ks * (n_img - 1.0) / n_img;
        let shift = Complex::new(ph.cos(), ph.sin());
        let f = freq(k); // cycles/arcsec
        let gauss = (-2.0 * PI * PI * sigma * sigma * f * f).exp();
        let common = shift * (pixel * gauss);
        let elong = match &prof {
            Some(p) if along_x => profile_transfer(p, f),
            _ => Complex::new(1.0, 0.0),
        };
        tx.push(common * elong);
        ty.push(common);
    }
    let rotated = match &prof {
        Some(p) if !along_x => {
            // A few hundred bins of a tenth of a fine sample: the binning
            // moves light by at most 0.05 fine sample.
            let coarse = p.binned(0.1 * g.fine_sample_arcsec);
            let [c, s] = direction;
            let rows: Vec<Vec<Complex<f64>>> = (0..m)
                .into_par_iter()
                .map(|ky| {
                    (0..m)
                        .map(|kx| {
                            if nyquist(kx) || nyquist(ky) {
                                Complex::new(0.0, 0.0)
                            } else {
                                profile_transfer(&coarse, c * freq(kx) + s * freq(ky))
                            }
                        })
                        .collect()
                })
                .collect();
            Some(rows.concat())
        }
        _ => None,
    };
    Transfers {
        x: tx,
        y: ty,
        rotated,
    }
}
