//! The fixed-point slopes against exact real arithmetic on the same
//! calibrated values: SPEC.md §5 promises `slope + reference` is within 1/2
//! of `Sx / 2F` in 2^-16 pixel (unless saturated). The oracle recomputes
//! selection by sorting and the centre of gravity in f64, straight from the
//! definitions (level filter excluded: its rounding is §4's, not §5's).

use brightpix::engine_runner::HostEngine;
use brightpix_protocol::SelectionRule;
use brightpix_tests::{case, Case};
use proptest::prelude::*;

/// SPEC.md §2, in i64.
fn calibrated(case: &Case, frame: &[u16], pixel: usize) -> i64 {
    let mut d = 16 * frame[pixel] as i64 - case.background.as_ref().map_or(0, |b| b[pixel] as i64);
    if let Some(gain) = &case.gain {
        d = (d * gain[pixel] as i64).div_euclid(4096);
    }
    if let Some(t) = case.threshold {
        if d < t as i64 {
            d = 0;
        }
    }
    d
}

/// Exact centre of gravity of one window, in pixels, from its calibrated
/// values: (x, y, flux), or None when invalid.
fn oracle(case: &Case, frame: &[u16], index: usize) -> (Option<(f64, f64)>, i64) {
    let w = case.windows[index];
    let width = case.camera.width as usize;
    let mut pixels = Vec::new();
    for j in 0..w.height as usize {
        for i in 0..w.width as usize {
            let pixel = (w.y as usize + j) * width + w.x as usize + i;
            pixels.push((calibrated(case, frame, pixel), i, j));
        }
    }
    let n = match &case.pixels {
        brightpix_tests::PixelCounts::All(n) => *n as usize,
        brightpix_tests::PixelCounts::PerSubaperture(list) => list[index] as usize,
    };
    let mut sorted: Vec<i64> = pixels.iter().map(|p| p.0).collect();
    sorted.sort_unstable_by(|a, b| b.cmp(a));
    let v = |k: usize| sorted[k - 1];
    let weights: Vec<i64> = if n >= pixels.len() {
        pixels.iter().map(|p| p.0).collect()
    } else {
        let below: Vec<i64> = sorted.iter().copied().filter(|&p| p < v(n)).collect();
        let (keep, level): (Box<dyn Fn(i64) -> bool>, Option<i64>) = match case.rule {
            SelectionRule::Threshold => (Box::new(|p| p >= v(n)), None),
            SelectionRule::SubtractNext => (Box::new(|p| p > v(n + 1)), Some(v(n + 1))),
            SelectionRule::SubtractNextDistinct => {
                (Box::new(|p| p >= v(n)), below.first().copied())
            }
            SelectionRule::SubtractMean { count } => {
                let take: Vec<i64> = below.iter().copied().take(count as usize).collect();
                let level = (!take.is_empty())
                    .then(|| (take.iter().sum::<i64>() as f64 / take.len() as f64).floor() as i64);
                (Box::new(|p| p >= v(n)), level)
            }
        };
        pixels
            .iter()
            .map(|&(p, _, _)| match (keep(p), level) {
                (false, _) => 0,
                (true, Some(l)) => (p - l).max(0),
                (true, None) => p,
            })
            .collect()
    };
    let flux: i64 = weights.iter().sum();
    if flux <= case.min_flux {
        return (None, flux);
    }
    let f = flux as f64;
    let sx: f64 = weights
        .iter()
        .zip(&pixels)
        .map(|(&w, p)| w as f64 * p.1 as f64)
        .sum();
    let sy: f64 = weights
        .iter()
        .zip(&pixels)
        .map(|(&w, p)| w as f64 * p.2 as f64)
        .sum();
    (
        Some((
            sx / f - (w.width as f64 - 1.0) / 2.0,
            sy / f - (w.height as f64 - 1.0) / 2.0,
        )),
        flux,
    )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    #[test]
    fn fixed_point_slopes_are_within_the_quantisation_bound((mut case, frames, _) in case()) {
        case.level_filter = None;
        let config = case.view();
        let mut engine = HostEngine::new(config).unwrap();
        let results = engine.process(frames.iter().map(Vec::as_slice), usize::MAX).unwrap();
        for (frame, results) in frames.iter().zip(&results) {
            for r in results {
                let index = r.index as usize;
                let (exact, flux) = oracle(&case, frame, index);
                prop_assert_eq!(r.flux, flux);
                match exact {
                    None => prop_assert!(!r.valid && r.slope_x == 0 && r.slope_y == 0),
                    Some((x, y)) => {
                        prop_assert!(r.valid);
                        let [rx, ry] = case.reference_slopes.as_ref().map_or([0, 0], |s| s[index]);
                        for (got, reference, exact) in [(r.slope_x, rx, x), (r.slope_y, ry, y)] {
                            let want = exact * 65536.0 - reference as f64;
                            if got == i32::MAX || got == i32::MIN {
                                prop_assert!(want >= i32::MAX as f64 - 1.0 || want <= i32::MIN as f64 + 1.0);
                            } else {
                                // 1/2 unit of 2^-16 pixel, plus f64 rounding of the sums.
                                let tolerance = 0.5 + 1e-9 * want.abs().max(1.0);
                                prop_assert!((got as f64 - want).abs() <= tolerance,
                                    "sub-aperture {}: got {} want {}", index, got, want);
                            }
                        }
                    }
                }
            }
        }
    }
}
