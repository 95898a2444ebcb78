//! # Monte-Carlo Shack-Hartmann simulator (image formation)
//!
//! Makes the images of one Shack-Hartmann sub-aperture the way Basden, Myers
//! & Gendron (2011, "Wavefront sensing with a brightest pixel selection
//! algorithm") §2.2-3 describe: a fresh von Kármán turbulence realisation
//! per frame, the lenslet's spot formed by FFT, photon and read noise, a
//! background, and the noiseless image whose centre of gravity is the "true"
//! slope of the paper's metric R (eq. 1). Brightest-pixel selection,
//! calibration and evaluation are elsewhere: the firmware engine is applied
//! to [`SpotFrame::raw`].
//!
//! ```no_run
//! use brightpix::simulator::{SimulationParams, Simulator};
//! let sim = Simulator::new(SimulationParams::canary()).unwrap();
//! let frame = sim.subaperture_frame(0, 42);
//! assert_eq!(frame.raw.len(), 16 * 16);
//! let frames = sim.frames(42, 0, 1000); // in parallel, reproducible
//! # let _ = frames;
//! ```
//!
//! ## One sub-aperture per frame
//! A frame is one sub-aperture image from an independent realisation. The
//! paper's metric is an RMS over all slopes of all frames, and every NGS
//! sub-aperture has the same statistics, so independent single sub-apertures
//! give the same estimate of R with less correlation between samples than
//! 49 sub-apertures cut from one screen (neighbours' tilts are correlated),
//! for about the same cost per spot (the spot's FFTs dominate). The LGS cases
//! of the paper are one sub-aperture position anyway.
//!
//! ## Optics
//! The spot is `|FFT(A exp(i phi))|^2` of the lenslet pupil `A` (a circle of
//! `pupil_samples` samples across, anti-aliased) zero-padded to
//! `psf_fft_size`. The paper treats the diffraction spot as a parameter (an
//! Airy pattern of a given diameter to the first minimum, 0.7" by default,
//! while a 0.6 m sub-aperture at 640 nm would give 0.54"). It is realised by
//! computing the diffraction at the **effective wavelength**
//! `lambda_eff = theta_Airy d / 2.439` at which the real sub-aperture
//! diameter `d` gives the requested Airy diameter, with the turbulence's
//! optical path difference converted to phase at `lambda_eff` (equivalently:
//! the phase at the WFS wavelength scaled by `lambda/lambda_eff`). Consequences:
//! - wavefront tilt moves the spot by exactly the geometric angle, so spot
//!   motion (the slope) and its statistics, including the outer-scale
//!   effect, are exactly those of the real sub-aperture;
//! - the seeing-limited blur is that at `lambda_eff`: `d/r0` is computed with
//!   `r0(lambda_eff)` (2.60 instead of 3.57 at 640 nm for the defaults) and
//!   the long-exposure seeing width scales as `lambda_eff^(-1/5)` (5% narrower
//!   than at 640 nm for 0.7", 9% wider for 0.35").
//!
//! The pupil is sampled so that one fine sample of the FFT is `pixel/q`:
//! `pupil_samples = 2.439 psf_fft_size (pixel/q) / theta_Airy`. `q` is
//! chosen so the intensity is Nyquist sampled (x1.1), and the screen spacing
//! is `d/pupil_samples` (24-48 samples across `d`).
//!
//! ## Detector integration
//! The intensity (on the PSF grid, cropped or zero-padded to the image grid
//! of `fov_factor` = 2 detector fields: light beyond it is dropped, like a
//! field stop) is Fourier transformed; its spectrum is multiplied by the
//! pixel's box transfer function (exact integration over each pixel: the
//! intensity is band-limited), by the source's transfer function (LGS), and
//! by a shift putting the optical axis at the detector centre (the corner of
//! the four middle pixels); the spectrum is then folded (aliased) onto the
//! detector pixel grid and inverse transformed, which gives exactly the
//! pixel-integrated values at the pixel centres. The noiseless image is
//! normalised to `photons` over the detector (detected photons).
//!
//! ## Turbulence
//! See [`turbulence`]: FFT screen of 4 sub-aperture diameters plus
//! subharmonics, with tilt-preserving cell weights, von Kármán spectrum with
//! `r0` scaled as `lambda^(6/5)` and outer scale `L0`.
//!
//! ## Laser guide stars
//! Elongation is along x. The beacon is a Gaussian of FWHM 0.28" convolved
//! with the elongation profile: the beam at altitude `z` is seen from a
//! sub-aperture at distance `b` from the launch axis at angle `-b/z`, so a
//! profile in altitude maps to a profile in angle (exactly, not only to first
//! order `b dz / z^2`); it is centred on its centroid. Rayleigh: uniform
//! backscatter over the gate `H +- Delta/2`, `H` = 20 km, `b` = 1.8 m (the
//! centre of an edge sub-aperture: 3 x 0.6 m), giving 0.46", 0.93" and 1.39"
//! for 500, 1000 and 1500 m. Sodium: two Gaussian layers at 90 and 90+s km,
//! peak densities 0.4 and 0.6, half widths at half maximum 3.5 and 2 km,
//! `b` = 21 m, 1.5"/pixel, 1000 photons ([`SimulationParams::sodium`]).
//! The `1/z^2` fall-off of the return and the air density gradient are
//! neglected; the LGS's turbulence is that of the NGS path.
//!
//! ## Noise
//! `raw = clamp(round((Poisson(I) + N(0, read_noise))/gain + background +
//! background_error), 0, 2^bits - 1)`. The background carries no shot noise
//! (it is a detector offset that the paper adds and subtracts; with shot
//! noise the paper's SNR of ~6 would not hold). Calibration subtracts
//! [`Simulator::calibration_background`] (`background`), so
//! `background_error` counts remain.
//!
//! ## Random numbers
//! Each frame draws from ChaCha8 streams keyed by `(seed, frame_index,
//! stream)`: stream 0 for the turbulence, 1 for the noise. Results do not
//! depend on threads, and runs that differ only in noise parameters share
//! the same turbulence (common random numbers).

pub mod atmosphere;
pub mod camera;
mod optics;
mod params;
pub mod turbulence;

#[cfg(test)]
mod tests;

use std::sync::Arc;

use rand::rngs::ChaCha8Rng;
use rand::SeedableRng;
use rand_distr::{Distribution, Gamma, Poisson, StandardNormal};
use rayon::prelude::*;
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};

pub use optics::{Geometry, AIRY_DIAMETER_LAMBDA_OVER_D, AIRY_FWHM_PER_DIAMETER, HWHM_PER_SIGMA};
pub use params::{Sampling, SimulationParams, Source, SpotModel, SubaperturePupil};
pub use turbulence::{gtilt_variance_rad2, von_karman_psd, ARCSEC_PER_RAD};

use turbulence::{ScreenBuffers, ScreenGenerator};

/// Invalid simulation parameters.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SimError {
    #[error("invalid simulation parameter: {0}")]
    Invalid(String),
}

/// One sub-aperture image of one frame. Images are row-major, `size x size`,
/// row = y, column = x; slopes are `[x, y]` in pixels from the sub-aperture
/// centre (centre of gravity minus `(size - 1) / 2`).
#[derive(Clone, Debug, PartialEq)]
pub struct SpotFrame {
    /// Side of the images (pixels).
    pub size: usize,
    /// Expected photo-electrons per pixel, no noise, no background; sums to
    /// `photons`.
    pub noiseless: Vec<f64>,
    /// The camera's image: counts with background, photon and read noise.
    pub raw: Vec<u16>,
    /// Centre of gravity of `noiseless` (all pixels, no selection): the
    /// paper's `S_true`.
    pub true_slope: [f64; 2],
    /// The wavefront's average gradient over the pupil (G-tilt), as the
    /// spot displacement in pixels it would cause on an infinite detector.
    pub phase_slope: [f64; 2],
    /// Pixels clamped at the camera's maximum count.
    pub saturated: usize,
    /// The fraction of the spot's light (on the computed image grid, see
    /// [`Geometry::image_grid_pixels`]) that falls on the detector: below 1
    /// the sub-aperture truncates the spot (the rest is lost, like behind a
    /// field stop, and `noiseless` is normalised to `photons` without it).
    pub field_fraction: f64,
}

/// Reusable buffers for [`Simulator::frame_into`] (one per thread).
#[derive(Default)]
pub struct Workspace {
    screen: ScreenBuffers,
    phase: Vec<f64>,
    field: Vec<Complex<f64>>,
    field_t: Vec<Complex<f64>>,
    image: Vec<Complex<f64>>,
    image_t: Vec<Complex<f64>>,
    folded_x: Vec<Complex<f64>>,
    small: Vec<Complex<f64>>,
    small_t: Vec<Complex<f64>>,
    scratch: Vec<Complex<f64>>,
}

/// The simulator: immutable after construction and `Sync`, so one instance
/// serves all threads.
pub struct Simulator {
    params: SimulationParams,
    geometry: Geometry,
    pupil: Vec<f64>,
    screen: Option<ScreenGenerator>,
    fft_psf: Arc<dyn Fft<f64>>,
    fft_img: Arc<dyn Fft<f64>>,
    ifft_small: Arc<dyn Fft<f64>>,
    /// For each image-grid DFT index, the PSF-grid samples (index, weight)
    /// at the same angle (see [`optics::grid_map`]).
    grid_map: Vec<[(usize, f64); 2]>,
    transfers: optics::Transfers,
    max_count: f64,
}

/// Random stream for `(seed, frame, stream)`.
fn stream_rng(seed: u64, frame: u64, stream: u64) -> ChaCha8Rng {
    let mut key = [0u8; 32];
    key[..8].copy_from_slice(&seed.to_le_bytes());
    key[8..16].copy_from_slice(&frame.to_le_bytes());
    key[16..24].copy_from_slice(&stream.to_le_bytes());
    key[24..].copy_from_slice(b"brightpx");
    ChaCha8Rng::from_seed(key)
}

/// `dst[c][r] = src[r][c]` for a `rows x cols` `src`.
fn transpose(src: &[Complex<f64>], dst: &mut [Complex<f64>], rows: usize, cols: usize) {
    const B: usize = 16;
    for r0 in (0..rows).step_by(B) {
        for c0 in (0..cols).step_by(B) {
            for r in r0..(r0 + B).min(rows) {
                for c in c0..(c0 + B).min(cols) {
                    dst[c * rows + r] = src[r * cols + c];
                }
            }
        }
    }
}

impl Simulator {
    /// Validates the parameters and precomputes the sampling, the pupil, the
    /// FFT plans and the transfer functions.
    pub fn new(params: SimulationParams) -> Result<Self, SimError> {
        params.validate()?;
        let geometry = Geometry::new(&params)?;
        let g = &geometry;
        let mut planner = FftPlanner::new();
        let pupil = match &params.pupil {
            None => optics::pupil_mask(g.pupil_samples, g.pupil_array),
            Some(cut) => optics::cut_pupil_mask(
                g.pupil_samples,
                g.pupil_array,
                g.subaperture_diameter_m,
                params.telescope_diameter_m,
                cut,
            ),
        };
        if pupil.iter().all(|&a| a == 0.0) {
            return Err(SimError::Invalid(
                "the sub-aperture is entirely outside the telescope pupil".into(),
            ));
        }
        let screen = params.turbulence.then(|| {
            ScreenGenerator::new(
                g.screen_fft_size,
                g.pupil_array,
                g.pupil_sample_m,
                g.r0_effective_m,
                params.outer_scale_m,
                g.subharmonic_levels,
                &mut planner,
            )
        });
        let fft_psf = planner.plan_fft_forward(g.psf_fft_size);
        let fft_img = planner.plan_fft_forward(g.image_fft_size);
        let ifft_small = planner.plan_fft_inverse(g.image_grid_pixels);
        let grid_map = optics::grid_map(g.psf_fft_size, g.image_fft_size);
        let transfers = optics::transfers(g, &params.source);
        let max_count = ((1u32 << params.bit_depth) - 1) as f64;
        Ok(Self {
            params,
            geometry,
            pupil,
            screen,
            fft_psf,
            fft_img,
            ifft_small,
            grid_map,
            transfers,
            max_count,
        })
    }

    pub fn params(&self) -> &SimulationParams {
        &self.params
    }

    /// The derived sampling and optics numbers.
    pub fn geometry(&self) -> &Geometry {
        &self.geometry
    }

    /// Side of the sub-aperture image (pixels).
    pub fn size(&self) -> usize {
        self.params.pixels_per_subaperture as usize
    }

    /// The background (counts) that calibration subtracts: `background`;
    /// the camera's true background is `background + background_error`.
    pub fn calibration_background(&self) -> f64 {
        self.params.background
    }

    /// The paper's SNR estimate (eq. 2): `n / sqrt(n + sigma^2 N_pix)`.
    pub fn paper_snr(&self) -> f64 {
        let n = self.params.photons;
        let npix = (self.size() * self.size()) as f64;
        n / (n + self.params.read_noise_e.powi(2) * npix).sqrt()
    }

    /// Theoretical per-axis G-tilt variance of the turbulence in pixels^2 (0
    /// without turbulence): what `phase_slope` should show.
    pub fn theoretical_tilt_variance_px2(&self) -> f64 {
        if !self.params.turbulence {
            return 0.0;
        }
        let p = &self.params;
        let rad2 = gtilt_variance_rad2(
            p.r0_m,
            p.r0_wavelength_m,
            p.outer_scale_m,
            self.geometry.subaperture_diameter_m,
        );
        rad2 * (ARCSEC_PER_RAD / p.pixel_scale_arcsec).powi(2)
    }

    /// A new set of buffers for [`Simulator::frame_into`].
    pub fn workspace(&self) -> Workspace {
        Workspace::default()
    }

    /// Frame `frame_index` of the run `seed`, no extra tilt.
    pub fn subaperture_frame(&self, frame_index: u64, seed: u64) -> SpotFrame {
        self.frame_into(&mut self.workspace(), frame_index, seed, [0.0, 0.0])
    }

    /// Frame `frame_index` of the run `seed` with a pure wavefront tilt
    /// added that moves the spot by `tilt_px` = `[x, y]` pixels (the
    /// linearity study uses this with `turbulence = false`).
    pub fn subaperture_frame_with_tilt(
        &self,
        frame_index: u64,
        seed: u64,
        tilt_px: [f64; 2],
    ) -> SpotFrame {
        self.frame_into(&mut self.workspace(), frame_index, seed, tilt_px)
    }

    /// Frames `first .. first + count` of run `seed`, computed in parallel
    /// (rayon); identical to computing them one by one.
    pub fn frames(&self, seed: u64, first: u64, count: usize) -> Vec<SpotFrame> {
        (0..count)
            .into_par_iter()
            .map_init(
                || self.workspace(),
                |ws, i| self.frame_into(ws, first + i as u64, seed, [0.0, 0.0]),
            )
            .collect()
    }

    /// Frames `first + i` with tilt `tilts[i]`, in parallel.
    pub fn frames_with_tilts(&self, seed: u64, first: u64, tilts: &[[f64; 2]]) -> Vec<SpotFrame> {
        tilts
            .par_iter()
            .enumerate()
            .map_init(
                || self.workspace(),
                |ws, (i, &t)| self.frame_into(ws, first + i as u64, seed, t),
            )
            .collect()
    }

    /// Computes one frame using the buffers of `ws`.
    pub fn frame_into(
        &self,
        ws: &mut Workspace,
        frame_index: u64,
        seed: u64,
        tilt_px: [f64; 2],
    ) -> SpotFrame {
        let phase_slope = self.pupil_phase(ws, frame_index, seed, tilt_px);
        self.image_and_camera(ws, frame_index, seed, phase_slope)
    }

    /// Side of the lenslet's phase array (samples), and the sample spacing
    /// (m): the shape [`Simulator::frame_from_phase`] takes.
    pub fn phase_sampling(&self) -> (usize, f64) {
        (self.geometry.pupil_array, self.geometry.pupil_sample_m)
    }

    /// One frame from a given lenslet phase instead of the simulator's own
    /// independent screen: `opd_m` is the optical path difference (m) over
    /// the `n x n` samples of [`Simulator::phase_sampling`], row-major
    /// `[y][x]`, e.g. cut from a layered atmosphere. Photon and read noise
    /// are drawn from the streams of `(seed, frame_index)` as for
    /// [`Simulator::frame_into`].
    pub fn frame_from_opd(
        &self,
        ws: &mut Workspace,
        opd_m: &[f64],
        frame_index: u64,
        seed: u64,
    ) -> SpotFrame {
        let ns = self.geometry.pupil_array;
        assert_eq!(opd_m.len(), ns * ns, "OPD must be {ns}x{ns} samples");
        let k = 2.0 * std::f64::consts::PI / self.geometry.effective_wavelength_m;
        ws.phase.clear();
        ws.phase.extend(opd_m.iter().map(|v| v * k));
        let phase_slope = self.phase_gtilt(&ws.phase);
        self.image_and_camera(ws, frame_index, seed, phase_slope)
    }

    /// The G-tilt (pixels, `[x, y]`) of a lenslet optical path difference
    /// given as for [`Simulator::frame_from_opd`]: what
    /// [`SpotFrame::phase_slope`] reports for it.
    pub fn opd_gtilt_px(&self, opd_m: &[f64]) -> [f64; 2] {
        let ns = self.geometry.pupil_array;
        assert_eq!(opd_m.len(), ns * ns, "OPD must be {ns}x{ns} samples");
        let k = 2.0 * std::f64::consts::PI / self.geometry.effective_wavelength_m;
        let phase: Vec<f64> = opd_m.iter().map(|v| v * k).collect();
        self.phase_gtilt(&phase)
    }

    fn image_and_camera(
        &self,
        ws: &mut Workspace,
        frame_index: u64,
        seed: u64,
        phase_slope: [f64; 2],
    ) -> SpotFrame {
        let (noiseless, field_fraction) = self.spot_image(ws);
        let npx = self.size();
        let mut sx = 0.0;
        let mut sy = 0.0;
        let mut sum = 0.0;
        for y in 0..npx {
            for x in 0..npx {
                let v = noiseless[y * npx + x];
                sx += v * x as f64;
                sy += v * y as f64;
                sum += v;
            }
        }
        let c = (npx as f64 - 1.0) / 2.0;
        let true_slope = [sx / sum - c, sy / sum - c];
        let (raw, saturated) = self.camera(&noiseless, frame_index, seed);
        SpotFrame {
            size: npx,
            noiseless,
            raw,
            true_slope,
            phase_slope,
            saturated,
            field_fraction,
        }
    }

    /// Fills `ws.phase` (`pupil_array^2`, radians at the effective
    /// wavelength) with turbulence plus the tilt; returns the G-tilt in
    /// pixels.
    fn pupil_phase(
        &self,
        ws: &mut Workspace,
        frame: u64,
        seed: u64,
        tilt_px: [f64; 2],
    ) -> [f64; 2] {
        let g = &self.geometry;
        let ns = g.pupil_array;
        ws.phase.clear();
        ws.phase.resize(ns * ns, 0.0);
        if let Some(screen) = &self.screen {
            let mut rng = stream_rng(seed, frame, 0);
            screen.generate(&mut rng, &mut ws.screen, &mut ws.phase);
        }
        // A tilt of t pixels = t q fine samples = a phase ramp of
        // 2 pi t q / M_psf per pupil sample.
        let k = 2.0 * std::f64::consts::PI * g.oversampling as f64 / g.psf_fft_size as f64;
        if tilt_px != [0.0, 0.0] {
            let c = ns as f64 / 2.0 - 0.5;
            for y in 0..ns {
                for x in 0..ns {
                    ws.phase[y * ns + x] +=
                        k * (tilt_px[0] * (x as f64 - c) + tilt_px[1] * (y as f64 - c));
                }
            }
        }
        self.phase_gtilt(&ws.phase)
    }

    /// G-tilt of a lenslet phase (radians at the effective wavelength) in
    /// pixels: the pupil-weighted mean of the finite differences.
    fn phase_gtilt(&self, ph: &[f64]) -> [f64; 2] {
        let g = &self.geometry;
        let ns = g.pupil_array;
        let k = 2.0 * std::f64::consts::PI * g.oversampling as f64 / g.psf_fft_size as f64;
        let a = &self.pupil;
        let (mut gx, mut wx, mut gy, mut wy) = (0.0, 0.0, 0.0, 0.0);
        for y in 0..ns {
            for x in 0..ns {
                let i = y * ns + x;
                if x + 1 < ns {
                    let w = a[i] * a[i + 1];
                    gx += w * (ph[i + 1] - ph[i]);
                    wx += w;
                }
                if y + 1 < ns {
                    let w = a[i] * a[i + ns];
                    gy += w * (ph[i + ns] - ph[i]);
                    wy += w;
                }
            }
        }
        [gx / wx / k, gy / wy / k]
    }

    /// From `ws.phase`, the noiseless detector image normalised to `photons`,
    /// and the fraction of the grid's light on the detector.
    fn spot_image(&self, ws: &mut Workspace) -> (Vec<f64>, f64) {
        let g = &self.geometry;
        let (ns, mp, mi, nimg) = (
            g.pupil_array,
            g.psf_fft_size,
            g.image_fft_size,
            g.image_grid_pixels,
        );
        let scratch_len = self
            .fft_psf
            .get_inplace_scratch_len()
            .max(self.fft_img.get_inplace_scratch_len())
            .max(self.ifft_small.get_inplace_scratch_len());
        ws.scratch.resize(scratch_len, Complex::default());

        // Field in the zero-padded pupil plane: rows y < ns are non-zero.
        ws.field.clear();
        ws.field.resize(mp * mp, Complex::default());
        for y in 0..ns {
            for x in 0..ns {
                let a = self.pupil[y * ns + x];
                if a > 0.0 {
                    let p = ws.phase[y * ns + x];
                    ws.field[y * mp + x] = Complex::new(a * p.cos(), a * p.sin());
                }
            }
        }
        self.fft_psf
            .process_with_scratch(&mut ws.field[..ns * mp], &mut ws.scratch);
        ws.field_t.resize(mp * mp, Complex::default());
        transpose(&ws.field, &mut ws.field_t, mp, mp);
        self.fft_psf
            .process_with_scratch(&mut ws.field_t, &mut ws.scratch);
        // ws.field_t[kx][ky]: the field's spectrum, transposed.

        // Intensity on the image grid, still transposed ([x][y]).
        ws.image.clear();
        ws.image.resize(mi * mi, Complex::default());
        for (a, ma) in self.grid_map.iter().enumerate() {
            let dst = &mut ws.image[a * mi..(a + 1) * mi];
            for &(pa, wa) in ma.iter().filter(|(_, w)| *w != 0.0) {
                let src = &ws.field_t[pa * mp..(pa + 1) * mp];
                for (d, mb) in dst.iter_mut().zip(&self.grid_map) {
                    for &(pb, wb) in mb {
                        d.re += wa * wb * src[pb].norm_sqr();
                    }
                }
            }
        }
        // Spectrum: along y (rows of the transposed array), then along x.
        self.fft_img
            .process_with_scratch(&mut ws.image, &mut ws.scratch);
        ws.image_t.resize(mi * mi, Complex::default());
        transpose(&ws.image, &mut ws.image_t, mi, mi);
        self.fft_img
            .process_with_scratch(&mut ws.image_t, &mut ws.scratch);
        // ws.image_t[ky][kx].

        // Multiply by the transfer functions and fold onto the pixel grid.
        ws.folded_x.clear();
        ws.folded_x.resize(mi * nimg, Complex::default());
        let tr = &self.transfers;
        for ky in 0..mi {
            let row = &ws.image_t[ky * mi..(ky + 1) * mi];
            let out = &mut ws.folded_x[ky * nimg..(ky + 1) * nimg];
            match &tr.rotated {
                None => {
                    for (kx, (v, t)) in row.iter().zip(&tr.x).enumerate() {
                        out[kx % nimg] += v * t;
                    }
                }
                Some(rot) => {
                    let r = &rot[ky * mi..(ky + 1) * mi];
                    for (kx, ((v, t), e)) in row.iter().zip(&tr.x).zip(r).enumerate() {
                        out[kx % nimg] += v * t * e;
                    }
                }
            }
        }
        ws.small.clear();
        ws.small.resize(nimg * nimg, Complex::default());
        for ky in 0..mi {
            let t = tr.y[ky];
            let src = &ws.folded_x[ky * nimg..(ky + 1) * nimg];
            let dst = &mut ws.small[(ky % nimg) * nimg..(ky % nimg + 1) * nimg];
            for (d, s) in dst.iter_mut().zip(src) {
                *d += s * t;
            }
        }
        // Inverse transform on the pixel grid.
        self.ifft_small
            .process_with_scratch(&mut ws.small, &mut ws.scratch);
        ws.small_t.resize(nimg * nimg, Complex::default());
        transpose(&ws.small, &mut ws.small_t, nimg, nimg);
        self.ifft_small
            .process_with_scratch(&mut ws.small_t, &mut ws.scratch);
        // ws.small_t[x][y].

        let npx = self.size();
        let off = (nimg - npx) / 2;
        let mut img = vec![0.0; npx * npx];
        for y in 0..npx {
            for x in 0..npx {
                img[y * npx + x] = ws.small_t[(x + off) * nimg + (y + off)].re.max(0.0);
            }
        }
        let total: f64 = img.iter().sum();
        let grid_total: f64 = ws.small_t.iter().map(|v| v.re.max(0.0)).sum();
        let scale = self.params.photons / total;
        img.iter_mut().for_each(|v| *v *= scale);
        (img, (total / grid_total).min(1.0))
    }

    /// The camera: photon noise, read noise, gain, background, digitisation.
    fn camera(&self, noiseless: &[f64], frame: u64, seed: u64) -> (Vec<u16>, usize) {
        let p = &self.params;
        let mut rng = stream_rng(seed, frame, 1);
        let offset = p.background + p.background_error;
        let mut saturated = 0;
        let raw = noiseless
            .iter()
            .map(|&mean| {
                let mut e = if mean > 0.0 {
                    Poisson::new(mean).map_or(mean, |d| d.sample(&mut rng))
                } else {
                    0.0
                };
                if p.em_excess_noise {
                    e = em_register(e, &mut rng);
                }
                if p.read_noise_e > 0.0 {
                    let n: f64 = StandardNormal.sample(&mut rng);
                    e += p.read_noise_e * n;
                }
                let c = (e / p.gain_e_per_count + offset).round();
                if c >= self.max_count {
                    saturated += 1;
                }
                c.clamp(0.0, self.max_count) as u16
            })
            .collect();
        (raw, saturated)
    }
}

/// An EMCCD's multiplication register at high gain, in photo-electron units
/// (output charge over the gain): `n` electrons in, Gamma(`n`, 1) out (the
/// sum of `n` exponential cascades), mean `n` and variance `n`, which
/// doubles the variance of Poisson photo-electrons.
pub fn em_register(n: f64, rng: &mut impl rand::Rng) -> f64 {
    if n <= 0.0 {
        return 0.0;
    }
    Gamma::new(n, 1.0).map_or(n, |g| g.sample(rng))
}
