//! Plain least-squares tomography, the paper's reconstructor (§3.10:
//! "least-squares tomographic wavefront reconstruction ... reconstructing
//! phase at the layer heights"), beside the MMSE one of
//! [`super::reconstructor`].
//!
//! The same layer model (bilinear nodes at `d/2` on each layer, `s = G x`)
//! but no prior: the layers' phase is the minimum-norm least-squares
//! solution `x^ = G^+ s`, regularised only by discarding or damping the
//! small singular values of `G` (`G = U S V^T`, largest singular value
//! `s_max`):
//!
//! - **truncated SVD** `tsvd:R`: `x^ = V S_R^+ U^T s`, the singular values
//!   below `R s_max` set to zero;
//! - **Tikhonov** `tikhonov:R`: `x^ = argmin |s - G x|^2 + alpha |x|^2`
//!   with `alpha = (R s_max)^2`, i.e. each mode filtered by `s / (s^2 +
//!   alpha)` (half the pseudo-inverse's gain at `s = R s_max`).
//!
//! Without the turbulence's covariance, the layers' split of what every
//! sensor sees alike (tip-tilt and low orders common to all directions) is
//! left to the minimum norm, and noise in the weakly measured modes is not
//! damped by the prior: this is what makes plain least squares more
//! sensitive to slope noise than the MMSE estimate. The DM projection is
//! the MMSE path's: `M = F P x^`.

use anyhow::{bail, Context, Result};
use nalgebra::DMatrix;

use super::reconstructor::Tomography;

/// How the small singular values of `G` are handled.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LeastSquares {
    /// Singular values below this fraction of the largest are discarded.
    TruncatedSvd(f64),
    /// `alpha = (this fraction of the largest singular value)^2`.
    Tikhonov(f64),
}

impl LeastSquares {
    /// Parses `tsvd:R` or `tikhonov:R` (`R` in (0, 1)).
    pub fn parse(text: &str) -> Result<LeastSquares> {
        let (kind, value) = text
            .split_once(':')
            .with_context(|| format!("{text:?}: expected tsvd:R or tikhonov:R"))?;
        let r: f64 = value
            .trim()
            .parse()
            .with_context(|| format!("{text:?}: R"))?;
        if !(r > 0.0 && r < 1.0) {
            bail!("{text:?}: R must be in (0, 1), a fraction of the largest singular value");
        }
        Ok(match kind.trim() {
            "tsvd" => LeastSquares::TruncatedSvd(r),
            "tikhonov" => LeastSquares::Tikhonov(r),
            _ => bail!("{text:?}: expected tsvd:R or tikhonov:R"),
        })
    }

    /// The name in outputs: `ls-tsvd:R` or `ls-tikhonov:R`.
    pub fn label(&self) -> String {
        match self {
            LeastSquares::TruncatedSvd(r) => format!("ls-tsvd:{r}"),
            LeastSquares::Tikhonov(r) => format!("ls-tikhonov:{r}"),
        }
    }

    /// The filter applied to singular value `s` (the pseudo-inverse's `1/s`
    /// for a mode kept in full).
    fn filter(&self, s: f64, s_max: f64) -> f64 {
        match *self {
            LeastSquares::TruncatedSvd(r) => {
                if s >= r * s_max {
                    1.0 / s
                } else {
                    0.0
                }
            }
            LeastSquares::Tikhonov(r) => {
                let alpha = (r * s_max).powi(2);
                s / (s * s + alpha)
            }
        }
    }
}

/// A least-squares reconstructor and what its regularisation kept.
pub struct LeastSquaresReconstructor {
    /// DM commands (m) from slopes (px).
    pub m: DMatrix<f64>,
    /// The layer phases (m, nodes) from slopes: `V f(S) U^T`.
    pub layers: DMatrix<f64>,
    /// Singular values of `G` (px/m), largest first.
    pub singular_values: Vec<f64>,
    /// Modes at or above `R s_max` (for Tikhonov: passed at more than half
    /// the pseudo-inverse's gain).
    pub modes_kept: usize,
}

impl Tomography {
    /// The plain least-squares reconstructor of `ls` on this layer model.
    pub fn least_squares(&self, ls: LeastSquares) -> LeastSquaresReconstructor {
        // G is wide (slopes < nodes): its thin SVD has one mode per slope.
        let svd = self.g.clone().svd(true, true);
        let u = svd.u.expect("U requested");
        let v_t = svd.v_t.expect("V^T requested");
        let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
        order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
        let s_max = svd.singular_values.max();
        let r = match ls {
            LeastSquares::TruncatedSvd(r) | LeastSquares::Tikhonov(r) => r,
        };
        // V diag(f) U^T, accumulated from the filtered U^T rows.
        let mut fu_t = u.transpose();
        for (k, mut row) in fu_t.row_iter_mut().enumerate() {
            row *= ls.filter(svd.singular_values[k], s_max);
        }
        let layers = v_t.transpose() * fu_t;
        let m = &self.fp * &layers;
        LeastSquaresReconstructor {
            m,
            layers,
            singular_values: order.iter().map(|&k| svd.singular_values[k]).collect(),
            modes_kept: svd
                .singular_values
                .iter()
                .filter(|&&s| s >= r * s_max)
                .count(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_names() {
        assert_eq!(
            LeastSquares::parse("tsvd:0.05").unwrap(),
            LeastSquares::TruncatedSvd(0.05)
        );
        assert_eq!(
            LeastSquares::parse("tikhonov:0.1").unwrap(),
            LeastSquares::Tikhonov(0.1)
        );
        assert_eq!(LeastSquares::TruncatedSvd(0.05).label(), "ls-tsvd:0.05");
        for bad in ["tsvd", "tsvd:0", "tsvd:1", "svd:0.1", "tikhonov:x"] {
            assert!(LeastSquares::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn filters_follow_their_definitions() {
        let t = LeastSquares::TruncatedSvd(0.1);
        assert_eq!(t.filter(2.0, 10.0), 0.5);
        assert_eq!(t.filter(0.5, 10.0), 0.0);
        let k = LeastSquares::Tikhonov(0.1);
        // Half the pseudo-inverse's gain at s = R s_max, nearly all of it
        // well above.
        assert!((k.filter(1.0, 10.0) - 0.5).abs() < 1e-12);
        assert!((k.filter(10.0, 10.0) * 10.0 - 1.0).abs() < 0.011);
    }
}
