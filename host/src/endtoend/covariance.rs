//! The von Kármán phase covariance, the prior of the tomographic
//! reconstructor.
//!
//! `B(r) = sigma^2 2^(1/6) / Gamma(5/6) x^(5/6) K_(5/6)(x)`, `x = 2 pi r /
//! L0`, with the phase variance `sigma^2 = (6 pi / 5) C (L0/r0)^(5/3)` =
//! `0.0863 (L0/r0)^(5/3)` rad^2 (`C` the constant of
//! [`von_karman_psd`](crate::simulator::von_karman_psd): the variance is
//! `int Phi(f) 2 pi f df`). `K_nu` is the modified Bessel function of the
//! second kind, from its integral `int_0^inf exp(-x cosh t) cosh(nu t) dt`
//! (trapezoidal rule, exponentially convergent for this integrand).

use crate::simulator::turbulence::VON_KARMAN_CONSTANT;

/// `Gamma(5/6)`.
const GAMMA_5_6: f64 = 1.128_787_029_908_125_7;

/// `K_nu(x)` for `x > 0`.
pub fn bessel_k(nu: f64, x: f64) -> f64 {
    assert!(x > 0.0, "K_nu(x) needs x > 0");
    const H: f64 = 0.01;
    // The integrand rises until x sinh t = nu, then falls for good.
    let peak = (nu / x).asinh();
    let mut sum = 0.5 * (-x).exp();
    let mut t = H;
    loop {
        let term = (-x * t.cosh() + nu * t).exp() * 0.5 * (1.0 + (-2.0 * nu * t).exp());
        sum += term;
        if t > peak && term < 1e-17 * sum {
            break;
        }
        t += H;
    }
    sum * H
}

/// Phase variance (rad^2, at the wavelength of `r0`) of von Kármán
/// turbulence with Fried parameter `r0` and outer scale `l0` (m, finite).
pub fn phase_variance(r0: f64, l0: f64) -> f64 {
    1.2 * std::f64::consts::PI * VON_KARMAN_CONSTANT * (l0 / r0).powf(5.0 / 3.0)
}

/// Phase covariance (rad^2) between two points `r` metres apart.
pub fn phase_covariance(r: f64, r0: f64, l0: f64) -> f64 {
    let var = phase_variance(r0, l0);
    let x = 2.0 * std::f64::consts::PI * r / l0;
    if x < 1e-10 {
        return var;
    }
    var * 2f64.powf(1.0 / 6.0) / GAMMA_5_6 * x.powf(5.0 / 6.0) * bessel_k(5.0 / 6.0, x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bessel_k_matches_closed_forms() {
        // K_(1/2)(x) = sqrt(pi / (2x)) exp(-x).
        for &x in &[1e-3, 0.1, 1.0, 5.0] {
            let exact = (std::f64::consts::PI / (2.0 * x)).sqrt() * (-x).exp();
            let k = bessel_k(0.5, x);
            assert!((k / exact - 1.0).abs() < 1e-10, "{x}: {k} {exact}");
        }
    }

    /// `D(r)` by an independent route: the phase PSD integrated over
    /// `f_y` in closed form (`int (a^2 + y^2)^(-11/6) dy = a^(-8/3) sqrt(pi)
    /// Gamma(4/3) / Gamma(11/6)`), then `D(r) = 2 int Phi_x(f_x) (1 -
    /// cos(2 pi f_x r)) df_x` by Simpson's rule, with the tail beyond `F`
    /// (where the cosine averages out) in closed form.
    fn structure_function_from_psd(r: f64, r0: f64, l0: f64) -> f64 {
        const GAMMA_4_3: f64 = 0.892_979_511_569_249_2;
        const GAMMA_11_6: f64 = 0.940_655_858_232_114_5;
        let c = VON_KARMAN_CONSTANT * r0.powf(-5.0 / 3.0) * std::f64::consts::PI.sqrt() * GAMMA_4_3
            / GAMMA_11_6;
        let f0sq = 1.0 / (l0 * l0);
        let integrand = |f: f64| {
            c * (f * f + f0sq).powf(-4.0 / 3.0) * (1.0 - (2.0 * std::f64::consts::PI * f * r).cos())
        };
        // f = t^3 makes the integrand smooth at 0 (it goes as f^(-2/3)
        // between 1/L0 and 1/r).
        let top = 400.0 / r;
        let n = 400_000;
        let h = top.cbrt() / n as f64;
        let g = |t: f64| integrand(t * t * t) * 3.0 * t * t;
        let mut s = g(0.0) + g(top.cbrt());
        for i in 1..n {
            s += if i % 2 == 1 { 4.0 } else { 2.0 } * g(i as f64 * h);
        }
        let tail = c * 3.0 / 5.0 * top.powf(-5.0 / 3.0);
        // Both signs of f_x.
        2.0 * 2.0 * (s * h / 3.0 + tail)
    }

    #[test]
    fn structure_function_matches_the_psd() {
        // D(r) = 2 (B(0) - B(r)) against the PSD's own D(r).
        for &(r0, l0) in &[(0.125, 30.0), (0.1, 5.0), (0.2, 300.0)] {
            for &r in &[0.05, 0.3, 1.0, 4.0] {
                let d = 2.0 * (phase_covariance(0.0, r0, l0) - phase_covariance(r, r0, l0));
                let k = structure_function_from_psd(r, r0, l0);
                assert!((d / k - 1.0).abs() < 2e-3, "L0 {l0} r {r}: {d} {k}");
            }
        }
        // Kolmogorov's 6.88 (r/r0)^(5/3) is approached slowly, as (r/L0)^(1/3).
        let d = 2.0 * (phase_covariance(0.0, 0.125, 1e5) - phase_covariance(0.1, 0.125, 1e5));
        let k = 6.883_877 * (0.1f64 / 0.125).powf(5.0 / 3.0);
        assert!(d < k && d > 0.97 * k, "{d} {k}");
        // A finite outer scale lowers it: D(L0) well below Kolmogorov's.
        let (r0, l0) = (0.125, 30.0);
        let d = 2.0 * (phase_covariance(0.0, r0, l0) - phase_covariance(30.0, r0, l0));
        assert!(d < 0.7 * 6.88 * (30.0 / r0).powf(5.0 / 3.0));
        // And the covariance falls monotonically to 0.
        let b: Vec<f64> = [0.0, 1.0, 10.0, 100.0, 1000.0]
            .iter()
            .map(|&r| phase_covariance(r, r0, l0))
            .collect();
        assert!(b.windows(2).all(|w| w[1] < w[0]) && b[4] < 1e-6 * b[0]);
    }
}
