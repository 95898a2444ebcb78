//! Tests of the variants of issue 26: least-squares tomography, noise
//! weights, per-sub-aperture N, a reconstructor's profile unlike the
//! atmosphere's.

use super::least_squares::LeastSquares;
use super::tests::single_layer_on_axis;
use super::*;

/// Mean square of `phi - H M s` over the episode's frames, and of the DM's
/// best fit of `phi` (the floor).
fn residual_and_fitting(e2e: &EndToEnd, m: &DMatrix<f64>, data: &EpisodeData) -> (f64, f64) {
    let sci = &e2e.science;
    let r = &data.phi_now - &sci.h * (m * &data.s_low);
    let fit = &data.phi_now - &sci.h * (&sci.fit * &data.phi_now);
    (
        r.norm_squared() / r.len() as f64,
        fit.norm_squared() / fit.len() as f64,
    )
}

#[test]
fn least_squares_recovers_a_known_layer_without_noise() {
    let mut s = single_layer_on_axis();
    s.least_squares = Some(LeastSquares::TruncatedSvd(1e-3));
    s.least_squares_nodes = 1;
    let e2e = EndToEnd::new(s, 5).unwrap();
    let fried = e2e.ls_tomography.as_ref().expect("built");
    let loose = fried.least_squares(LeastSquares::TruncatedSvd(1e-3));
    let tight = fried.least_squares(LeastSquares::TruncatedSvd(0.5));
    let tikhonov = fried.least_squares(LeastSquares::Tikhonov(1e-3));
    // On the MMSE's d/2 lattice the minimum norm, not the turbulence,
    // fills what the slopes cannot see.
    let fine = e2e
        .tomography
        .least_squares(LeastSquares::TruncatedSvd(1e-3));
    // Fried geometry, one layer: fewer nodes than slopes, and a loose
    // truncation keeps all but the unmeasurable modes (piston, waffle).
    assert!(fried.nodes < fried.slopes() && fried.nodes < e2e.tomography.nodes);
    assert!(loose.modes_kept > tight.modes_kept && tight.modes_kept > 0);
    assert!(
        loose.modes_kept + 3 >= fried.nodes,
        "{} of {}",
        loose.modes_kept,
        fried.nodes
    );
    let (mut sums, mut fitting, mut misfit, mut slopes) = ([0.0; 4], 0.0, 0.0, 0.0);
    for e in 0..4 {
        let data = e2e.simulate_episode(4, e, e * 5);
        let reconstructors = [&loose, &tight, &tikhonov, &fine];
        for (k, (acc, r)) in sums.iter_mut().zip(reconstructors).enumerate() {
            let (res, fit) = residual_and_fitting(&e2e, &r.m, &data);
            *acc += res;
            if k == 0 {
                fitting += fit;
            }
        }
        // A layer the model can represent is recovered exactly: its slopes
        // give it back (up to the invisible piston and waffle).
        let x0 = &loose.layers * &data.s_low;
        let s0 = &fried.g * &x0;
        let x1 = &loose.layers * &s0;
        misfit += (&x1 - &x0).norm_squared();
        slopes += x0.norm_squared();
    }
    let nm = |v: f64| (v / 4.0).sqrt() * 1e9;
    let [loose_nm, tight_nm, tikhonov_nm, fine_nm] = sums.map(nm);
    let fitting_nm = nm(fitting);
    let numbers = format!(
        "tsvd 1e-3 {loose_nm:.1} nm, tsvd 0.5 {tight_nm:.1} nm, tikhonov 1e-3 {tikhonov_nm:.1} nm, d/2 nodes {fine_nm:.1} nm, fitting {fitting_nm:.1} nm"
    );
    eprintln!("{numbers}");
    assert!(misfit < 1e-12 * slopes, "{misfit} {slopes}");
    // Within the bilinear model's own error of the DM's floor with every
    // mode (199.5 nm against 134.1 nm of fitting when written: the corner
    // nodes' G-tilt is not the turbulence's), far from it with few.
    assert!(
        loose_nm > fitting_nm && loose_nm < 1.6 * fitting_nm,
        "{numbers}"
    );
    assert!((tikhonov_nm / loose_nm - 1.0).abs() < 0.05, "{numbers}");
    assert!(tight_nm > 1.5 * loose_nm, "{numbers}");
    assert!(fine_nm > loose_nm, "{numbers}");
}

#[test]
fn noise_weights_discount_the_noisy_slopes() {
    let e2e = EndToEnd::new(Scenario::canary(), 2).unwrap();
    let t = &e2e.tomography;
    let n = t.slopes();
    let uniform = t.reconstructor_weighted(&vec![0.05; n]);
    assert!((&uniform - t.reconstructor(0.05)).norm() <= 1e-12 * uniform.norm());
    // A slope a thousand times noisier than the rest is nearly ignored.
    let mut v = vec![0.05; n];
    v[7] = 50.0;
    let weighted = t.reconstructor_weighted(&v);
    let col = |m: &DMatrix<f64>, k: usize| m.column(k).norm();
    assert!(col(&weighted, 7) < 0.05 * col(&uniform, 7));
    assert!((col(&weighted, 8) / col(&uniform, 8) - 1.0).abs() < 0.5);
    // Pooling: every slope of a sub-aperture gets its mean over sensors and
    // axes.
    let n_sub = e2e.lenslets.subapertures.len();
    let raw: Vec<f64> = (0..n)
        .map(|i| ((i / 2) % n_sub) as f64 + (i % 2) as f64)
        .collect();
    let pooled = e2e.per_subaperture_noise(&raw);
    for (i, p) in pooled.iter().enumerate() {
        assert!((p - (((i / 2) % n_sub) as f64 + 0.5)).abs() < 1e-12);
    }
}

#[test]
fn per_subaperture_n_follows_the_lit_fraction() {
    let mut s = Scenario::canary();
    s.pixels_by_light = true;
    let e2e = EndToEnd::new(s, 2).unwrap();
    let c = e2e.engine_config(Method::SUBTRACT_NEXT, 20);
    let crate::config_file::PixelCounts::PerSubaperture(n) = c.pixels else {
        panic!("per-sub-aperture counts expected");
    };
    assert_eq!(n.len(), 36);
    // Each sub-aperture selects its share of N: the partly lit ones
    // (fewer photons) fewer pixels, the fully lit ones N.
    let expected: Vec<u16> = e2e
        .lenslets
        .subapertures
        .iter()
        .map(|s| ((20.0 * s.lit).round() as u16).max(1))
        .collect();
    assert_eq!(n, expected);
    let fewer = n.iter().filter(|&&k| k < 20).count();
    assert!((1..36).contains(&fewer), "{n:?}");
    assert!(n.iter().all(|k| (1..=20).contains(k)), "{n:?}");
    // All pixels stay all pixels.
    let all = e2e.engine_config(Method::SUBTRACT_NEXT, 256);
    assert_eq!(all.pixels, crate::config_file::PixelCounts::All(256));
}

#[test]
fn a_mismatched_profile_changes_the_reconstructor_only() {
    let known = EndToEnd::new(Scenario::canary(), 2).unwrap();
    let mut s = Scenario::canary();
    s.model_layers = Some(vec![(0.0, 0.5), (1000.0, 0.4), (8000.0, 0.1)]);
    let wrong = EndToEnd::new(s, 2).unwrap();
    assert_ne!(known.tomography.nodes, wrong.tomography.nodes);
    let data = known.simulate_episode(3, 0, 0);
    let other = wrong.simulate_episode(3, 0, 0);
    assert_eq!(data.raw, other.raw, "the atmosphere is the same");
    let (good, _) = residual_and_fitting(&known, &known.tomography.reconstructor(1e-4), &data);
    let (bad, _) = residual_and_fitting(&wrong, &wrong.tomography.reconstructor(1e-4), &data);
    assert!(bad > good, "{bad} {good}");
    let mut s = Scenario::canary();
    s.model_layers = Some(vec![(0.0, -1.0)]);
    assert!(EndToEnd::new(s, 2).is_err());
}
