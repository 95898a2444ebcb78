use super::*;

fn small_batch(params: SimulationParams, frames: usize) -> Batch {
    let sim = Simulator::new(params).unwrap();
    Batch::simulate(&sim, 11, frames, 64, &|_| {})
}

#[test]
fn all_pixels_on_a_noiseless_image_is_the_true_slope() {
    // No noise, no background: the engine's all-pixel slope equals the f64
    // centre of gravity up to the counts' rounding.
    let sim = Simulator::new(SimulationParams {
        photons: 1e6,
        gain_e_per_count: 16.0,
        read_noise_e: 0.0,
        ..SimulationParams::canary()
    })
    .unwrap();
    let batch = Batch::simulate(&sim, 3, 20, 20, &|_| {});
    let s = batch.score(Method::SUBTRACT_NEXT, 1000).unwrap();
    assert!(s.all_pixels);
    assert_eq!(s.pixels, 256);
    // Photon noise of 1e6 photons only: a few 1e-3 pixel.
    assert!(s.r(Axis::Both).value < 0.01, "{:?}", s.r(Axis::Both));
    assert_eq!(s.invalid, 0);
}

#[test]
fn config_is_one_window_with_the_calibrated_background() {
    let batch = small_batch(SimulationParams::canary(), 2);
    let c = batch.config(Method::subtract_mean(4).with_level_filter(3), 20);
    assert_eq!(c.windows.len(), 1);
    assert_eq!(c.camera.width, 16);
    assert_eq!(c.background.as_ref().unwrap()[0], 800);
    assert_eq!(c.rule, SelectionRule::SubtractMean { count: 4 });
    assert_eq!(c.level_filter, Some(LevelFilter { gain_shift: 3 }));
    assert_eq!(c.pixels, PixelCounts::All(20));
    assert!(c.validate().is_ok());
    assert_eq!(
        batch.config(Method::THRESHOLD, 9999).pixels,
        PixelCounts::All(256)
    );
}

#[test]
fn evaluate_covers_every_combination_once() {
    let batch = small_batch(SimulationParams::canary(), 50);
    let methods = [Method::SUBTRACT_NEXT, Method::THRESHOLD];
    let scores = evaluate(&batch, &methods, &[1, 20, 256, 300], &|| {}).unwrap();
    assert_eq!(scores.len(), 6);
    // All pixels is the same computation whatever the rule.
    let a = all_pixels(&scores, Method::SUBTRACT_NEXT).unwrap();
    let b = all_pixels(&scores, Method::THRESHOLD).unwrap();
    assert_eq!(a.errors, b.errors);
    let d = a.paired_difference(b, Axis::Both);
    assert_eq!(d.value, 0.0);
    assert!(find(&scores, Method::SUBTRACT_NEXT, 20).is_some());
    for s in &scores {
        let r = s.r(Axis::Both);
        assert!(r.value.is_finite() && r.se > 0.0 && r.se < r.value);
    }
}

#[test]
fn subtract_next_is_exactly_blind_to_a_constant_background_error() {
    // Same turbulence and noise draws; the raw images differ by exactly the
    // (integer) error, which subtract-next removes exactly.
    let a = small_batch(SimulationParams::canary(), 40);
    let b = small_batch(
        SimulationParams {
            background_error: 10.0,
            ..SimulationParams::canary()
        },
        40,
    );
    let sa = a.score(Method::SUBTRACT_NEXT, 20).unwrap();
    let sb = b.score(Method::SUBTRACT_NEXT, 20).unwrap();
    assert_eq!(sa.errors, sb.errors);
    let ta = a.score(Method::THRESHOLD, 20).unwrap();
    let tb = b.score(Method::THRESHOLD, 20).unwrap();
    assert_ne!(ta.errors, tb.errors);
}

#[test]
fn statistics() {
    let s = Score {
        method: Method::SUBTRACT_NEXT,
        pixels: 1,
        all_pixels: false,
        invalid: 0,
        errors: vec![
            [1.0, 3f64.sqrt()],
            [-1.0, -(3f64.sqrt())],
            [2.0, 0.0],
            [-2.0, 0.0],
        ],
        direction: [1.0, 0.0],
    };
    let x = s.mse(Axis::X);
    assert_eq!(x.value, 2.5);
    // sample sd of [1,1,4,4] = sqrt(3), over sqrt(4)
    assert!((x.se - 3f64.sqrt() / 2.0).abs() < 1e-12);
    assert!((s.mse(Axis::Y).value - 1.5).abs() < 1e-12);
    assert!((s.mse(Axis::Both).value - 2.0).abs() < 1e-12);
    assert_eq!(s.mse(Axis::Along).value, s.mse(Axis::X).value);
    // Rotated by 90 degrees, along is y.
    let r = Score {
        direction: [0.0, 1.0],
        ..s.clone()
    };
    assert!((r.mse(Axis::Along).value - 1.5).abs() < 1e-12);
    assert!((r.mse(Axis::Across).value - 2.5).abs() < 1e-12);
    assert!((s.r(Axis::X).value - 2.5f64.sqrt()).abs() < 1e-12);
    let grid = default_pixel_grid(256);
    assert_eq!(grid.first(), Some(&1));
    assert_eq!(grid.last(), Some(&256));
    assert!(grid.contains(&20));
    let grid = default_pixel_grid(36);
    assert_eq!(grid.last(), Some(&36));
    assert!(grid.windows(2).all(|w| w[0] < w[1]));
    let big = default_pixel_grid(4096);
    assert_eq!(big.last(), Some(&4096));
    assert!(big.windows(2).all(|w| w[0] < w[1]));
}
