//! von Kármán turbulence: the phase power spectrum, an FFT phase screen with
//! subharmonics over one sub-aperture, and the theoretical G-tilt variance.
//!
//! # The phase screen
//!
//! Only one sub-aperture's worth of phase is needed per spot, but its tilt
//! must have the right statistics, and with a 30 m outer scale those come
//! from spatial frequencies far below 1/d. The screen is therefore:
//!
//! 1. an FFT screen (the classic spectral method) on a periodic `G x G` grid
//!    with the pupil's sample spacing `delta`, `G*delta` = `screen_factor`
//!    (4) sub-aperture diameters: `phi(x) = Re sum_k c_k a_k exp(2 pi i k.x/G)`
//!    with independent complex unit Gaussians `c_k` and `a_k^2` the phase
//!    power of the frequency cell around `k` (the `k = 0` cell excluded);
//! 2. plus subharmonics (Lane et al. 1992; Johansson & Gavel 1994): the
//!    excluded central cell is split 3x3, its 8 outer cells become modes of
//!    frequency `(a, b) df/3` (a, b in {-1, 0, 1}), and so on recursively for
//!    `levels` levels, so the lowest frequency is `df/3^levels` (chosen so
//!    that it is below `1/(5 L0)`);
//! 3. the sub-aperture is cut from one corner of the screen (the screen is
//!    statistically homogeneous, so any place is as good).
//!
//! Cell weights: sampling the PSD at a cell's centre underestimates the cells
//! next to the origin, where it varies fastest. For those cells (the eight
//! subharmonic modes of every level and the main-grid cells within 3 of the
//! origin) `a_k^2` is the cell integral of `PSD(f) |f|^2` divided by
//! `|f_k|^2`: such low frequencies act on a sub-aperture almost only as a
//! tilt proportional to `|f|`, so this keeps the tilt power of each cell.
//! With this, the G-tilt variance of the screen is within ~2% of theory for
//! L0 = 30 m (and ~1.5% low for L0 = 10 km); centre sampling alone gives
//! 7-10% low (checked by summing the discrete modes against the integral).
//!
//! The independent subharmonic modes are evaluated only on the sub-aperture
//! patch, as a sum of separable products (cheap).

use std::f64::consts::PI;
use std::sync::Arc;

use rand::Rng;
use rand_distr::{Distribution, StandardNormal};
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};

/// `0.0229 r0^(-5/3)`: the constant of the phase power spectrum
/// `Phi(f) = C r0^(-5/3) (f^2 + 1/L0^2)^(-11/6)` (f in cycles/m),
/// `C = Gamma(11/6)^2 / (2 pi^(11/3)) (24/5 Gamma(6/5))^(5/6)`.
pub const VON_KARMAN_CONSTANT: f64 = 0.022_895_587_108_555_2;

/// Arcseconds per radian.
pub const ARCSEC_PER_RAD: f64 = 180.0 * 3600.0 / PI;

/// von Kármán phase power spectral density (rad^2 m^2) at spatial frequency
/// `f` (cycles/m), for Fried parameter `r0` (m, at the phase's wavelength)
/// and outer scale `l0` (m; infinite for Kolmogorov).
pub fn von_karman_psd(f: f64, r0: f64, l0: f64) -> f64 {
    let f0sq = if l0.is_finite() { 1.0 / (l0 * l0) } else { 0.0 };
    VON_KARMAN_CONSTANT * r0.powf(-5.0 / 3.0) * (f * f + f0sq).powf(-11.0 / 6.0)
}

/// Bessel function of the first kind of order 1 (rational approximations of
/// Numerical Recipes §6.5; absolute error below 1e-8).
pub fn bessel_j1(x: f64) -> f64 {
    let ax = x.abs();
    if ax < 8.0 {
        let y = x * x;
        let a1 = x
            * (72362614232.0
                + y * (-7895059235.0
                    + y * (242396853.1
                        + y * (-2972611.439 + y * (15704.48260 + y * (-30.16036606))))));
        let a2 = 144725228442.0
            + y * (2300535178.0 + y * (18583304.74 + y * (99447.43394 + y * (376.9991397 + y))));
        a1 / a2
    } else {
        let z = 8.0 / ax;
        let y = z * z;
        let xx = ax - 2.356194491;
        let a1 = 1.0
            + y * (0.183105e-2
                + y * (-0.3516396496e-4 + y * (0.2457520174e-5 + y * (-0.240337019e-6))));
        let a2 = 0.04687499995
            + y * (-0.2002690873e-3
                + y * (0.8449199096e-5 + y * (-0.88228987e-6 + y * 0.105787412e-6)));
        let ans = (std::f64::consts::FRAC_2_PI / ax).sqrt() * (xx.cos() * a1 - z * xx.sin() * a2);
        if x < 0.0 {
            -ans
        } else {
            ans
        }
    }
}

/// Theoretical variance, per axis, of the G-tilt (the wavefront gradient
/// averaged over a circular aperture of diameter `d`, which is what the
/// centre of gravity of an untruncated spot measures), in rad^2 of angle:
///
/// `sigma^2 = pi lambda^2 int_0^inf Phi(f) f^3 [2 J1(pi d f)/(pi d f)]^2 df`.
///
/// Achromatic (`lambda^2 r0(lambda)^(-5/3)` is): give `r0` at any
/// `r0_wavelength`. For L0 = inf it is `0.170 (lambda/d)^2 (d/r0)^(5/3)`.
pub fn gtilt_variance_rad2(r0: f64, r0_wavelength: f64, outer_scale: f64, d: f64) -> f64 {
    let integrand = |f: f64| {
        let x = PI * d * f;
        let filt = if x < 1e-8 {
            1.0
        } else {
            let a = 2.0 * bessel_j1(x) / x;
            a * a
        };
        // d(ln f) measure: one more power of f.
        von_karman_psd(f, r0, outer_scale) * f.powi(4) * filt
    };
    let f_lo = 1e-8 / d;
    let (u0, u1) = (f_lo.ln(), (1e4 / d).ln());
    let n = 12_000; // even, for Simpson
    let h = (u1 - u0) / n as f64;
    let mut s = integrand(u0.exp()) + integrand(u1.exp());
    for i in 1..n {
        let w = if i % 2 == 1 { 4.0 } else { 2.0 };
        s += w * integrand((u0 + i as f64 * h).exp());
    }
    let mut integral = s * h / 3.0;
    // Below f_lo the filter is 1: add the Kolmogorov bound of the tail,
    // int_0^a f^(-2/3) df = 3 a^(1/3) (relative size ~1e-3; 0 for finite L0).
    if !outer_scale.is_finite() {
        integral += VON_KARMAN_CONSTANT * r0.powf(-5.0 / 3.0) * 3.0 * f_lo.cbrt();
    }
    PI * r0_wavelength * r0_wavelength * integral
}

/// Cell-integrated tilt-preserving weight: `int_cell Phi(f) |f|^2 d^2f /
/// |f_c|^2`, the cell `[cx +- w/2] x [cy +- w/2]` (cycles/m).
fn cell_weight(cx: f64, cy: f64, w: f64, r0: f64, l0: f64) -> f64 {
    const N: usize = 16;
    let fc2 = cx * cx + cy * cy;
    let mut s = 0.0;
    for i in 0..N {
        let fx = cx + w * ((i as f64 + 0.5) / N as f64 - 0.5);
        for j in 0..N {
            let fy = cy + w * ((j as f64 + 0.5) / N as f64 - 0.5);
            let f2 = fx * fx + fy * fy;
            s += von_karman_psd(f2.sqrt(), r0, l0) * f2;
        }
    }
    s * (w / N as f64) * (w / N as f64) / fc2
}

/// Generates the phase (radians) over an `patch x patch` corner of a random
/// FFT + subharmonic phase screen. Immutable and shareable between threads;
/// [`ScreenGenerator::generate`] takes its own buffers.
pub(crate) struct ScreenGenerator {
    /// Screen FFT size `G`.
    n: usize,
    /// Side of the patch returned.
    patch: usize,
    /// `a_k` (rad) in FFT order, row-major `[ky][kx]`; 0 at `k = 0`.
    amp: Vec<f64>,
    /// Per level, the amplitudes of the 9 modes `(a, b)`, index
    /// `(a+1)*3 + (b+1)`, 0 for the centre.
    sub_amp: Vec<[f64; 9]>,
    /// Per level and `a in {-1,0,1}`: `exp(2 pi i a t / (G 3^l))` for
    /// `t < patch`, flattened `[level][a+1][t]`.
    sub_basis: Vec<Complex<f64>>,
    ifft: Arc<dyn Fft<f64>>,
}

/// Buffers of one [`ScreenGenerator::generate`] call.
#[derive(Default)]
pub(crate) struct ScreenBuffers {
    spec: Vec<Complex<f64>>,
    spec_low: Vec<Complex<f64>>,
    cols: Vec<Complex<f64>>,
    scratch: Vec<Complex<f64>>,
    v: Vec<Complex<f64>>,
}

impl ScreenGenerator {
    /// `n`: FFT size; `patch`: side of the returned patch; `delta`: sample
    /// spacing (m); `r0` (m) at the wavelength of the returned phase; `l0`
    /// outer scale (m); `levels`: subharmonic levels.
    pub(crate) fn new(
        n: usize,
        patch: usize,
        delta: f64,
        r0: f64,
        l0: f64,
        levels: usize,
        planner: &mut FftPlanner<f64>,
    ) -> Self {
        assert!(patch <= n);
        let df = 1.0 / (n as f64 * delta);
        let signed = |k: usize| -> f64 {
            if k < n.div_ceil(2) {
                k as f64
            } else {
                k as f64 - n as f64
            }
        };
        let mut amp = vec![0.0; n * n];
        for ky in 0..n {
            let sy = signed(ky);
            for kx in 0..n {
                let sx = signed(kx);
                if sx == 0.0 && sy == 0.0 {
                    continue;
                }
                let var = if sx.abs().max(sy.abs()) <= 3.0 {
                    cell_weight(sx * df, sy * df, df, r0, l0)
                } else {
                    von_karman_psd((sx * sx + sy * sy).sqrt() * df, r0, l0) * df * df
                };
                amp[ky * n + kx] = var.sqrt();
            }
        }
        let mut sub_amp = Vec::with_capacity(levels);
        let mut sub_basis = Vec::with_capacity(levels * 3 * patch);
        for l in 1..=levels {
            let dfl = df / 3f64.powi(l as i32);
            let mut a9 = [0.0; 9];
            for a in -1i32..=1 {
                for b in -1i32..=1 {
                    if a == 0 && b == 0 {
                        continue;
                    }
                    let w = cell_weight(a as f64 * dfl, b as f64 * dfl, dfl, r0, l0);
                    a9[((a + 1) * 3 + (b + 1)) as usize] = w.sqrt();
                }
            }
            sub_amp.push(a9);
            // cycles per sample of the unit mode of this level
            let nu = dfl * delta;
            for a in -1i32..=1 {
                for t in 0..patch {
                    let ph = 2.0 * PI * a as f64 * nu * t as f64;
                    sub_basis.push(Complex::new(ph.cos(), ph.sin()));
                }
            }
        }
        let ifft = planner.plan_fft_inverse(n);
        Self {
            n,
            patch,
            amp,
            sub_amp,
            sub_basis,
            ifft,
        }
    }

    /// Fills `out` (`patch * patch`, row-major `[y][x]`) with a fresh screen.
    pub(crate) fn generate<R: Rng + ?Sized>(
        &self,
        rng: &mut R,
        bufs: &mut ScreenBuffers,
        out: &mut [f64],
    ) {
        self.generate_split(rng, bufs, out, None);
    }

    /// As [`generate`](Self::generate) (the same random numbers give the
    /// same `out`), and with `low = Some((buffer, cutoff))` also the same
    /// screen's low-pass part in `buffer`: the FFT cells with `|k_x|` and
    /// `|k_y|` below `cutoff` (cycles per sample, e.g. half a sample per
    /// sub-aperture for a Shack-Hartmann's Nyquist frequency) and every
    /// subharmonic. `out - buffer` is then the high-pass part.
    pub(crate) fn generate_split<R: Rng + ?Sized>(
        &self,
        rng: &mut R,
        bufs: &mut ScreenBuffers,
        out: &mut [f64],
        low: Option<(&mut [f64], f64)>,
    ) {
        let (n, p) = (self.n, self.patch);
        assert_eq!(out.len(), p * p);
        bufs.spec.resize(n * n, Complex::default());
        for (s, &a) in bufs.spec.iter_mut().zip(&self.amp) {
            let re: f64 = StandardNormal.sample(rng);
            let im: f64 = StandardNormal.sample(rng);
            *s = Complex::new(a * re, a * im);
        }
        let mut outs: Vec<&mut [f64]> = vec![out];
        if let Some((low, cutoff)) = low {
            assert_eq!(low.len(), p * p);
            bufs.spec_low.resize(n * n, Complex::default());
            let limit = cutoff * n as f64;
            for ky in 0..n {
                let fy = (super::optics::signed_index(ky, n) as f64).abs();
                for kx in 0..n {
                    let fx = (super::optics::signed_index(kx, n) as f64).abs();
                    let k = ky * n + kx;
                    bufs.spec_low[k] = if fx < limit && fy < limit {
                        bufs.spec[k]
                    } else {
                        Complex::default()
                    };
                }
            }
            let mut spec_low = std::mem::take(&mut bufs.spec_low);
            self.transform_patch(&mut spec_low, bufs, low);
            bufs.spec_low = spec_low;
            outs.push(low);
        }
        let mut spec = std::mem::take(&mut bufs.spec);
        self.transform_patch(&mut spec, bufs, outs[0]);
        bufs.spec = spec;
        self.add_subharmonics(rng, bufs, &mut outs);
    }

    /// The inverse transform of `spec` (destroyed) on the patch, using the
    /// other buffers of `bufs`.
    fn transform_patch(
        &self,
        spec: &mut [Complex<f64>],
        bufs: &mut ScreenBuffers,
        out: &mut [f64],
    ) {
        let (n, p) = (self.n, self.patch);
        bufs.cols.resize(p * n, Complex::default());
        let scratch_len = self.ifft.get_inplace_scratch_len();
        bufs.scratch.resize(scratch_len, Complex::default());
        // Inverse transform along x (every row), then along y for the
        // columns x < patch only.
        self.ifft.process_with_scratch(spec, &mut bufs.scratch);
        for x in 0..p {
            for y in 0..n {
                bufs.cols[x * n + y] = spec[y * n + x];
            }
        }
        self.ifft
            .process_with_scratch(&mut bufs.cols, &mut bufs.scratch);
        for y in 0..p {
            for x in 0..p {
                out[y * p + x] = bufs.cols[x * n + y].re;
            }
        }
    }

    /// Subharmonics: `sum_l sum_a e_{l,a}(x) V_{l,a}(y)` with `V_{l,a}(y) =
    /// sum_b c_{l,a,b} e_{l,b}(y)`, added to every one of `outs`.
    fn add_subharmonics<R: Rng + ?Sized>(
        &self,
        rng: &mut R,
        bufs: &mut ScreenBuffers,
        outs: &mut [&mut [f64]],
    ) {
        let p = self.patch;
        let levels = self.sub_amp.len();
        bufs.v.resize(3 * p, Complex::default());
        for l in 0..levels {
            let basis = &self.sub_basis[l * 3 * p..(l + 1) * 3 * p];
            bufs.v.iter_mut().for_each(|v| *v = Complex::default());
            for a in 0..3 {
                for b in 0..3 {
                    let amp = self.sub_amp[l][a * 3 + b];
                    if amp == 0.0 {
                        continue;
                    }
                    let re: f64 = StandardNormal.sample(rng);
                    let im: f64 = StandardNormal.sample(rng);
                    let c = Complex::new(amp * re, amp * im);
                    let eb = &basis[b * p..(b + 1) * p];
                    for (v, e) in bufs.v[a * p..(a + 1) * p].iter_mut().zip(eb) {
                        *v += c * e;
                    }
                }
            }
            for out in outs.iter_mut() {
                for y in 0..p {
                    let row = &mut out[y * p..(y + 1) * p];
                    for a in 0..3 {
                        let vy = bufs.v[a * p + y];
                        let ea = &basis[a * p..(a + 1) * p];
                        for (o, e) in row.iter_mut().zip(ea) {
                            *o += (vy * e).re;
                        }
                    }
                }
            }
        }
    }
}
