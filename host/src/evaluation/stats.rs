//! Statistics over scores: which N cannot be told from the best, where a
//! paired difference changes sign (with its uncertainty), and scores pooled
//! over several seeds.

use super::{Axis, Estimate, Score};

/// The N values (sorted) of `scores` (one method, one batch) whose R is not
/// worse than the best R by more than `sigmas` standard errors of the paired
/// difference: the flat bottom of the curve that the data cannot resolve.
/// The best N is an argmin over that range and moves within it from seed to
/// seed.
pub fn indistinguishable_from_best(scores: &[&Score], axis: Axis, sigmas: f64) -> Vec<usize> {
    let Some(best) = scores
        .iter()
        .min_by(|a, b| a.mse(axis).value.total_cmp(&b.mse(axis).value))
    else {
        return Vec::new();
    };
    let mut ns: Vec<usize> = scores
        .iter()
        .filter(|s| {
            let d = s.paired_difference(best, axis);
            d.value <= sigmas * d.se
        })
        .map(|s| s.pixels)
        .collect();
    ns.sort_unstable();
    ns
}

/// Where a difference measured at increasing `x` first changes sign, by
/// linear interpolation between the two bracketing points, with the
/// standard error propagated from theirs (delta method, the two treated as
/// independent). `None` if it never changes sign.
pub fn zero_crossing(points: &[(f64, Estimate)]) -> Option<Estimate> {
    zero_crossings(points).into_iter().next()
}

/// Every sign change of [`zero_crossing`]'s kind, in order of `x`.
pub fn zero_crossings(points: &[(f64, Estimate)]) -> Vec<Estimate> {
    points
        .windows(2)
        .filter_map(|w| {
            let ((x1, a), (x2, b)) = (w[0], w[1]);
            if a.value.signum() == b.value.signum() || a.value == b.value {
                return None;
            }
            let t = a.value / (a.value - b.value);
            let x = x1 + t * (x2 - x1);
            // dx/da = (x2 - x1) * -b / (a - b)^2, dx/db = (x2 - x1) * a / (a - b)^2
            let den = (a.value - b.value).powi(2);
            let da = (x2 - x1) * b.value / den;
            let db = (x2 - x1) * a.value / den;
            Some(Estimate {
                value: x,
                se: ((da * a.se).powi(2) + (db * b.se).powi(2)).sqrt(),
            })
        })
        .collect()
}

/// One score from the same (method, N) on several batches: the frames
/// concatenated, so R and paired differences are over all of them.
pub fn pooled(scores: &[&Score]) -> Score {
    let first = scores[0];
    let mut out = first.clone();
    out.errors = scores
        .iter()
        .flat_map(|s| s.errors.iter().copied())
        .collect();
    out.invalid = scores.iter().map(|s| s.invalid).sum();
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evaluation::Method;

    fn score(pixels: usize, errors: Vec<[f64; 2]>) -> Score {
        Score {
            method: Method::SUBTRACT_NEXT,
            pixels,
            all_pixels: false,
            invalid: 0,
            errors,
            direction: [1.0, 0.0],
        }
    }

    #[test]
    fn crossing_is_interpolated_with_its_error() {
        let e = |value, se| Estimate { value, se };
        let points = [
            (5.0, e(-0.2, 0.01)),
            (7.0, e(-0.1, 0.01)),
            (10.0, e(0.2, 0.01)),
        ];
        let c = zero_crossing(&points).unwrap();
        assert!((c.value - 8.0).abs() < 1e-12);
        assert!(c.se > 0.0 && c.se < 0.2);
        assert!(zero_crossing(&points[..2]).is_none());
    }

    #[test]
    fn flat_range_and_pooling() {
        // N = 2 has the same errors as N = 1 in another order (same R, a
        // noisy paired difference); N = 4 is clearly worse.
        let base: Vec<[f64; 2]> = (0..200)
            .map(|i| [((i * 37) % 11) as f64 - 5.0, 0.0])
            .collect();
        let a = score(1, base.clone());
        let b = score(2, base.iter().rev().copied().collect());
        let c = score(4, base.iter().map(|e| [e[0] * 2.0, 0.0]).collect());
        let flat = indistinguishable_from_best(&[&a, &b, &c], Axis::X, 2.0);
        assert_eq!(flat, vec![1, 2]);
        let p = pooled(&[&a, &c]);
        assert_eq!(p.errors.len(), 400);
    }
}
