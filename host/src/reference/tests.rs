//! Hand-computed examples. Every expected number is worked out in the
//! comments from SPEC.md, not from running the code.
//!
//! Conventions used throughout: without maps `p = 16 * r`. A slope is
//! `q = floor((S * 65536 + F) / (2F))` (§5). In a window of width `w` the
//! local column `i` has `a = 2i - (w - 1)`; with `h = 1`, `b = 0` so
//! `Sy = 0` and `qy = floor(F / 2F) = 0` for any `F >= 1`. A single weighted
//! pixel at `a` gives `q = floor(a * 32768 + 1/2) = a * 32768`.

use super::*;
use brightpix_protocol::{Calibration, Centroid, PixelCount, Selection as SelectionConfig};

fn window(x: u16, y: u16, width: u16, height: u16) -> SubapertureWindow {
    SubapertureWindow {
        x,
        y,
        width,
        height,
    }
}

/// 16-bit camera, no maps, no filter, `min_flux = 0`, one `N` for all.
fn config(
    width: u16,
    height: u16,
    windows: &[SubapertureWindow],
    rule: SelectionRule,
    n: u16,
) -> Config<'_> {
    Config {
        camera: Camera {
            width,
            height,
            bit_depth: 16,
        },
        windows,
        calibration: Calibration::default(),
        selection: SelectionConfig {
            rule,
            count: PixelCount::All(n),
            level_filter: None,
        },
        centroid: Centroid::default(),
        crop: None,
    }
}

fn run(config: &Config<'_>, frame: &[u16]) -> Vec<SubapertureOutput> {
    Reference::new(config)
        .expect("valid configuration")
        .process_frame(frame)
        .expect("valid frame")
}

fn out(index: usize, slope_x: i32, slope_y: i32, flux: i64, valid: bool) -> SubapertureOutput {
    SubapertureOutput {
        index,
        slope_x,
        slope_y,
        flux,
        valid,
    }
}

fn single(outputs: Vec<SubapertureOutput>) -> SubapertureOutput {
    assert_eq!(outputs.len(), 1);
    outputs[0]
}

#[test]
fn floor_div_and_shift_round_toward_minus_infinity() {
    assert_eq!(floor_div(7, 2), 3);
    assert_eq!(floor_div(-7, 2), -4);
    assert_eq!(floor_div(-8, 2), -4);
    assert_eq!(floor_div(0, 5), 0);
    assert_eq!(floor_div(-1, 4096), -1);
    assert_eq!(shift_right(-1, 12), -1);
    assert_eq!(shift_right(-4096, 12), -1);
    assert_eq!(shift_right(-4097, 12), -2);
    assert_eq!(shift_right(4095, 12), 0);
}

/// 1x1 windows: `N = 1 >= n = 1` is no selection, so `F = w = p` shows each
/// calibrated value; `a = b = 0` so valid slopes are `floor(F / 2F) = 0`.
#[test]
fn calibration_background_then_gain_with_floor() {
    let windows: Vec<_> = (0..6).map(|x| window(x, 0, 1, 1)).collect();
    let background = [20, 20, -16, 0, 4, 1];
    let gain = [5000, 5000, 4096, 0, 1024, 4095];
    let mut cfg = config(6, 1, &windows, SelectionRule::SubtractNext, 1);
    cfg.calibration.background = Some(&background);
    cfg.calibration.gain = Some(&gain);
    let frame = [1, 3, 10, 2, 0, 0];
    // pixel 0: d = 16 - 20 = -4; -4 * 5000 = -20000; -20000 / 4096 = -4.88 -> floor -5
    //          (truncation would give -4). F = -5 <= 0: invalid.
    // pixel 1: d = 48 - 20 = 28; 28 * 5000 = 140000 = 34 * 4096 + 736 -> 34.
    // pixel 2: d = 160 + 16 = 176; 176 * 4096 >> 12 = 176.
    // pixel 3: d = 32; G = 0 -> 0. F = 0 <= 0: invalid.
    // pixel 4: d = -4; -4 * 1024 = -4096 -> exactly -1.
    // pixel 5: d = -1; -1 * 4095 = -4095 -> floor(-0.9998) = -1 (truncation: 0).
    assert_eq!(
        run(&cfg, &frame),
        vec![
            out(0, 0, 0, -5, false),
            out(1, 0, 0, 34, true),
            out(2, 0, 0, 176, true),
            out(3, 0, 0, 0, false),
            out(4, 0, 0, -1, false),
            out(5, 0, 0, -1, false),
        ]
    );
}

/// The threshold is applied last (after background and gain), with `d < T`
/// strict, and also for a negative `T`.
#[test]
fn fixed_threshold_zeroes_values_below_it() {
    let windows: Vec<_> = (0..5).map(|x| window(x, 0, 1, 1)).collect();
    let background = [0, 0, 0, 100, 0];
    let gain = [4096, 4096, 4096, 4096, 2048];
    let mut cfg = config(5, 1, &windows, SelectionRule::SubtractNext, 1);
    cfg.calibration.background = Some(&background);
    cfg.calibration.gain = Some(&gain);
    cfg.calibration.threshold = Some(32);
    let frame = [1, 2, 3, 0, 1];
    // 16 < 32 -> 0; 32 is not < 32 -> 32; 48; -100 < 32 -> 0;
    // last: 16 * 2048 >> 12 = 8 < 32 -> 0 (the gain comes before the threshold).
    let fluxes: Vec<i64> = run(&cfg, &frame).iter().map(|o| o.flux).collect();
    assert_eq!(fluxes, vec![0, 32, 48, 0, 0]);
    // T = 10 distinguishes the order: 16 >= 10 would stay if thresholded
    // before the gain, but the gain makes it 8 < 10 -> 0.
    cfg.calibration.threshold = Some(10);
    let fluxes: Vec<i64> = run(&cfg, &frame).iter().map(|o| o.flux).collect();
    assert_eq!(fluxes, vec![16, 32, 48, 0, 0]);

    // Negative T = -10: d = -16 < -10 -> 0; d = -8 stays; d = -10 stays.
    let windows: Vec<_> = (0..3).map(|x| window(x, 0, 1, 1)).collect();
    let background = [16, 8, 10];
    let mut cfg = config(3, 1, &windows, SelectionRule::SubtractNext, 1);
    cfg.calibration.background = Some(&background);
    cfg.calibration.threshold = Some(-10);
    let fluxes: Vec<i64> = run(&cfg, &[0, 0, 0]).iter().map(|o| o.flux).collect();
    assert_eq!(fluxes, vec![0, -8, -10]);
}

/// A 3x3 window of distinct raw values
///
/// ```text
///        i=0 i=1 i=2        a = 2i - 2, b = 2j - 2
///  j=0:   1   2   3
///  j=1:   4   9   5
///  j=2:   6   7   8
/// ```
///
/// `p = 16r`. Descending raw: 9 8 7 6 5 4 3 2 1, so with N = 3:
/// v(3) = 7*16 = 112, v(4) = 96. The three brightest: 9 at (a, b) = (0, 0),
/// 8 at (2, 2), 7 at (0, 2).
const GRID_3X3: [u16; 9] = [1, 2, 3, 4, 9, 5, 6, 7, 8];

fn grid_config(rule: SelectionRule, n: u16) -> Config<'static> {
    static WINDOWS: [SubapertureWindow; 1] = [SubapertureWindow {
        x: 0,
        y: 0,
        width: 3,
        height: 3,
    }];
    config(3, 3, &WINDOWS, rule, n)
}

#[test]
fn three_by_three_each_rule() {
    // subtract-next, N = 3: K = p > 96 = {9, 8, 7}, L = 96.
    // w = 48 (0,0), 32 (2,2), 16 (0,2). F = 96, Sx = 64, Sy = 64 + 32 = 96.
    // qx = floor((64*65536 + 96) / 192) = floor(21845.83) = 21845
    // qy = floor((96*65536 + 96) / 192) = floor(32768.5) = 32768
    let cfg = grid_config(SelectionRule::SubtractNext, 3);
    assert_eq!(single(run(&cfg, &GRID_3X3)), out(0, 21845, 32768, 96, true));

    // threshold, N = 3: K = p >= 112, w = p: 144, 128, 112. F = 384,
    // Sx = 128*2 = 256, Sy = 128*2 + 112*2 = 480.
    // qx = floor((256*65536 + 384) / 768) = floor(21845.83) = 21845
    // qy = floor((480*65536 + 384) / 768) = floor(40960.5) = 40960
    let cfg = grid_config(SelectionRule::Threshold, 3);
    assert_eq!(
        single(run(&cfg, &GRID_3X3)),
        out(0, 21845, 40960, 384, true)
    );

    // subtract-next-distinct, N = 3: K = p >= 112, l = largest < 112 = 96:
    // the same weights as subtract-next here (no ties).
    let cfg = grid_config(SelectionRule::SubtractNextDistinct, 3);
    assert_eq!(single(run(&cfg, &GRID_3X3)), out(0, 21845, 32768, 96, true));

    // subtract-mean M = 2, N = 3: below 112: 96, 80 -> L = 176 / 2 = 88.
    // w = 56, 40, 24. F = 120, Sx = 40*2 = 80, Sy = 40*2 + 24*2 = 128.
    // qx = floor((80*65536 + 120) / 240) = floor(21845.83) = 21845
    // qy = floor((128*65536 + 120) / 240) = 8388728 / 240 = 34953.03 -> 34953
    let cfg = grid_config(SelectionRule::SubtractMean { count: 2 }, 3);
    assert_eq!(
        single(run(&cfg, &GRID_3X3)),
        out(0, 21845, 34953, 120, true)
    );

    // subtract-mean M = 16, N = 3: only 6 values below 112, c = 6:
    // 16 * (6+5+4+3+2+1) = 336, L = 336 / 6 = 56. w = 88, 72, 56. F = 216,
    // Sx = 72*2 = 144, Sy = 72*2 + 56*2 = 256.
    // qx = floor((144*65536 + 216) / 432) = floor(21845.83) = 21845
    // qy = floor((256*65536 + 216) / 432) = 16777432 / 432 = 38836.6 -> 38836
    let cfg = grid_config(SelectionRule::SubtractMean { count: 16 }, 3);
    assert_eq!(
        single(run(&cfg, &GRID_3X3)),
        out(0, 21845, 38836, 216, true)
    );
}

#[test]
fn no_selection_when_n_is_at_least_the_pixel_count() {
    // N = 9 = n and N = 10 > n: w = p for all, whatever the rule.
    // F = 16 * 45 = 720. Columns: i=0 holds 1+4+6 = 11, i=2 holds 3+5+8 = 16:
    // Sx = 16 * (-2*11 + 2*16) = 160. Rows: j=0 holds 6, j=2 holds 21:
    // Sy = 16 * (-2*6 + 2*21) = 480.
    // qx = floor((160*65536 + 720) / 1440) = floor(7282.28) = 7282
    // qy = floor((480*65536 + 720) / 1440) = floor(21845.83) = 21845
    for rule in [
        SelectionRule::Threshold,
        SelectionRule::SubtractNext,
        SelectionRule::SubtractNextDistinct,
        SelectionRule::SubtractMean { count: 3 },
    ] {
        for n in [9, 10, 20] {
            let cfg = grid_config(rule, n);
            assert_eq!(
                single(run(&cfg, &GRID_3X3)),
                out(0, 7282, 21845, 720, true),
                "{rule:?} N={n}"
            );
        }
    }
    // N = 8 = n - 1, subtract-next: v(9) = 16, K = p > 16 (all but the 1),
    // w = p - 16 = 16(r - 1). F = 16 * (45 - 9) = 576; sum(a) = sum(b) = 0
    // over the window, so Sx = 160, Sy = 480 as above.
    // qx = floor((160*65536 + 576) / 1152) = floor(9102.7) = 9102
    // qy = floor((480*65536 + 576) / 1152) = floor(27307.17) = 27307
    let cfg = grid_config(SelectionRule::SubtractNext, 8);
    assert_eq!(single(run(&cfg, &GRID_3X3)), out(0, 9102, 27307, 576, true));
}

/// A 1x5 window, raw 5 3 3 3 1 (p = 80 48 48 48 16), a = -4 -2 0 2 4.
/// With N = 2: v(2) = v(3) = v(4) = 48.
const TIES: [u16; 5] = [5, 3, 3, 3, 1];

fn ties_config(rule: SelectionRule, n: u16) -> Config<'static> {
    static WINDOWS: [SubapertureWindow; 1] = [SubapertureWindow {
        x: 0,
        y: 0,
        width: 5,
        height: 1,
    }];
    config(5, 1, &WINDOWS, rule, n)
}

#[test]
fn threshold_keeps_every_tie() {
    // K = p >= 48: four pixels although N = 2. w = 80, 48, 48, 48, 0.
    // F = 224, Sx = -320 + 48*(-2 + 0 + 2) = -320.
    // qx = floor((-320*65536 + 224) / 448) = floor(-46810.93) = -46811
    let cfg = ties_config(SelectionRule::Threshold, 2);
    assert_eq!(single(run(&cfg, &TIES)), out(0, -46811, 0, 224, true));
}

#[test]
fn subtract_next_with_tied_next_value_weighs_fewer_than_n() {
    // N = 2: v(3) = 48, K = p > 48 = {80}: one pixel, not two. w = 32 at a = -4.
    // F = 32, Sx = -128, qx = floor((-128*65536 + 32) / 64) = floor(-131071.5) = -131072
    let cfg = ties_config(SelectionRule::SubtractNext, 2);
    assert_eq!(single(run(&cfg, &TIES)), out(0, -131072, 0, 32, true));
    // N = 3: v(4) = 48 too, the same result.
    let cfg = ties_config(SelectionRule::SubtractNext, 3);
    assert_eq!(single(run(&cfg, &TIES)), out(0, -131072, 0, 32, true));
    // All equal, raw 3 3 3 3 3, N = 2: K = p > 48 is empty, F = 0 <= 0: invalid.
    assert_eq!(single(run(&cfg, &[3; 5])), out(0, 0, 0, 0, false));
}

#[test]
fn subtract_next_distinct_skips_ties() {
    // N = 2: K = p >= 48 (four pixels), l = largest < 48 = 16.
    // w = 64, 32, 32, 32, 0. F = 160, Sx = -256 + 32*(-2 + 0 + 2) = -256.
    // qx = floor((-256*65536 + 160) / 320) = floor(-52428.3) = -52429
    let cfg = ties_config(SelectionRule::SubtractNextDistinct, 2);
    assert_eq!(single(run(&cfg, &TIES)), out(0, -52429, 0, 160, true));
    // N = 4: K = p >= 48 still, the same.
    let cfg = ties_config(SelectionRule::SubtractNextDistinct, 4);
    assert_eq!(single(run(&cfg, &TIES)), out(0, -52429, 0, 160, true));
}

/// A 1x6 window, raw 9 4 4 2 1 1 (p = 144 64 64 32 16 16), a = -5 -3 -1 1 3 5.
#[test]
fn subtract_mean_counts_duplicates_and_may_use_fewer_than_m() {
    static WINDOWS: [SubapertureWindow; 1] = [SubapertureWindow {
        x: 0,
        y: 0,
        width: 6,
        height: 1,
    }];
    let frame = [9, 4, 4, 2, 1, 1];
    let mean = |m, n| config(6, 1, &WINDOWS, SelectionRule::SubtractMean { count: m }, n);

    // N = 2, M = 3: v(2) = 64, K = {144, 64, 64}; below 64: 32, 16, 16,
    // c = 3, L = floor(64 / 3) = 21. w = 123, 43, 43. F = 209,
    // Sx = -615 - 129 - 43 = -787.
    // qx = floor((-787*65536 + 209) / 418) = floor(-123389.05) = -123390
    assert_eq!(
        single(run(&mean(3, 2), &frame)),
        out(0, -123390, 0, 209, true)
    );
    // M = 16: c = min(16, 3) = 3, the same.
    assert_eq!(
        single(run(&mean(16, 2), &frame)),
        out(0, -123390, 0, 209, true)
    );
    // M = 2: c = 2, L = (32 + 16) / 2 = 24. w = 120, 40, 40. F = 200,
    // Sx = -600 - 120 - 40 = -760.
    // qx = floor((-760*65536 + 200) / 400) = floor(-124517.9) = -124518
    assert_eq!(
        single(run(&mean(2, 2), &frame)),
        out(0, -124518, 0, 200, true)
    );
    // N = 1, M = 2: v(1) = 144; the 2 largest below are 64 and 64
    // (duplicates counted), L = 64, w = 80 at a = -5. F = 80, Sx = -400,
    // qx = floor((-400*65536 + 80) / 160) = floor(-163839.5) = -163840
    assert_eq!(
        single(run(&mean(2, 1), &frame)),
        out(0, -163840, 0, 80, true)
    );
}

#[test]
fn negative_calibrated_values() {
    // Camera 4x1, B = 40 40 40 41, raw 5 2 1 0: p = 40, -8, -24, -41.
    let background = [40, 40, 40, 41];
    let frame = [5, 2, 1, 0];
    let three = [window(0, 0, 3, 1)]; // p = 40 -8 -24, a = -2 0 2
    let four = [window(0, 0, 4, 1)]; // p = 40 -8 -24 -41, a = -3 -1 1 3

    // subtract-next N = 1 on the three: v(2) = -8, K = p > -8 = {40},
    // w = 40 - (-8) = 48 at a = -2: F = 48, Sx = -96,
    // qx = floor((-96*65536 + 48) / 96) = floor(-65535.5) = -65536
    let mut cfg = config(4, 1, &three, SelectionRule::SubtractNext, 1);
    cfg.calibration.background = Some(&background);
    assert_eq!(single(run(&cfg, &frame)), out(0, -65536, 0, 48, true));

    // threshold N = 2 on the three: K = p >= -8, w = 40, -8 (a negative
    // weight). F = 32, Sx = -80, qx = floor((-80*65536 + 32) / 64)
    // = floor(-81919.5) = -81920
    let mut cfg = config(4, 1, &three, SelectionRule::Threshold, 2);
    cfg.calibration.background = Some(&background);
    assert_eq!(single(run(&cfg, &frame)), out(0, -81920, 0, 32, true));

    // subtract-mean N = 1, M = 3 on the four: below 40: -8, -24, -41, sum -73,
    // L = floor(-73 / 3) = floor(-24.33) = -25 (truncation: -24).
    // w = 40 + 25 = 65 at a = -3: F = 65, Sx = -195,
    // qx = floor((-195*65536 + 65) / 130) = floor(-98303.5) = -98304
    let mut cfg = config(4, 1, &four, SelectionRule::SubtractMean { count: 3 }, 1);
    cfg.calibration.background = Some(&background);
    assert_eq!(single(run(&cfg, &frame)), out(0, -98304, 0, 65, true));
}

#[test]
fn flux_at_or_below_min_flux_is_invalid_with_zero_slopes() {
    // The 3x3 subtract-next N = 3 case: F = 96, q = (21845, 32768).
    let references = [[1000, -2000]];
    let mut cfg = grid_config(SelectionRule::SubtractNext, 3);
    cfg.centroid.reference_slopes = Some(&references);
    // min_flux = 96: F = 96 is not > 96: invalid, slopes 0 (not -r), flux kept.
    cfg.centroid.min_flux = 96;
    assert_eq!(single(run(&cfg, &GRID_3X3)), out(0, 0, 0, 96, false));
    // min_flux = 95: valid, slope = q - r = (21845 - 1000, 32768 + 2000).
    cfg.centroid.min_flux = 95;
    assert_eq!(single(run(&cfg, &GRID_3X3)), out(0, 20845, 34768, 96, true));
}

/// 1x2 windows (a = -1, +1), no selection (N = 2 = n): Sx = p1 - p0,
/// F = p0 + p1 = 131072 = 2^17, so Sx * 65536 / 2F = Sx / 4 exactly.
#[test]
fn rounding_is_half_up_for_both_signs() {
    let windows: Vec<_> = (0..4).map(|k| window(2 * k, 0, 2, 1)).collect();
    // raw 4096 -> 65536, raw 4097 -> 65552; B sets p:
    // window 0: 65535, 65537 (Sx = +2 -> +0.5)
    // window 1: 65537, 65535 (Sx = -2 -> -0.5)
    // window 2: 65533, 65539 (Sx = +6 -> +1.5)
    // window 3: 65539, 65533 (Sx = -6 -> -1.5)
    let background = [1, 15, 15, 1, 3, 13, 13, 3];
    let frame = [4096, 4097, 4097, 4096, 4096, 4097, 4097, 4096];
    let mut cfg = config(8, 1, &windows, SelectionRule::SubtractNext, 2);
    cfg.calibration.background = Some(&background);
    // q = floor((Sx*65536 + 131072) / 262144) = floor(Sx/4 + 1/2):
    // +0.5 -> 1, -0.5 -> 0, +1.5 -> 2, -1.5 -> -1.
    assert_eq!(
        run(&cfg, &frame),
        vec![
            out(0, 1, 0, 131072, true),
            out(1, 0, 0, 131072, true),
            out(2, 2, 0, 131072, true),
            out(3, -1, 0, 131072, true),
        ]
    );
}

/// 1x2 windows, no selection, p = -32768 and 32769 (B = 32768 on raw 0;
/// raw 2049 -> 32784 - 15). F = 1 > 0, Sx = +-(32769 + 32768) = +-65537,
/// q = floor((+-65537*65536 + 1) / 2) = +-2147516416 (beyond i32).
#[test]
fn reference_slopes_are_subtracted_then_saturated() {
    let windows = [window(0, 0, 2, 1), window(2, 0, 2, 1)];
    let background = [32768, 15, 15, 32768];
    let frame = [0, 2049, 2049, 0];
    let mut cfg = config(4, 1, &windows, SelectionRule::Threshold, 2);
    cfg.calibration.background = Some(&background);
    // No reference: saturated to 2^31 - 1 and -2^31; qy = floor(1/2) = 0.
    assert_eq!(
        run(&cfg, &frame),
        vec![out(0, i32::MAX, 0, 1, true), out(1, i32::MIN, 0, 1, true),]
    );
    // r = (+2^22, 0), (-2^22, 0): 2147516416 - 4194304 = 2143322112 fits.
    let references = [[1 << 22, 0], [-(1 << 22), 0]];
    cfg.centroid.reference_slopes = Some(&references);
    assert_eq!(
        run(&cfg, &frame),
        vec![
            out(0, 2143322112, 0, 1, true),
            out(1, -2143322112, 0, 1, true),
        ]
    );
    // r = (-2^22, 5), (2^22, -5): saturated further out; y: 0 - 5, 0 + 5.
    let references = [[-(1 << 22), 5], [1 << 22, -5]];
    cfg.centroid.reference_slopes = Some(&references);
    assert_eq!(
        run(&cfg, &frame),
        vec![out(0, i32::MAX, -5, 1, true), out(1, i32::MIN, 5, 1, true),]
    );
}

/// Negative weights, and so saturation, also arise with the subtracting
/// rules when `l` is none (`w_p = p`), which §5's parenthesis does not list.
/// 1x3 window (a = -2 0 2), B = 32768 32768 15, raw 0 0 4097:
/// p = -32768, -32768, 65537. N = 2: v(2) = -32768, nothing below it, so
/// l = none for subtract-next-distinct and subtract-mean (c = 0): w = p.
/// F = 65537 - 65536 = 1, Sx = 2*65537 + 2*32768 = 196610,
/// q = floor((196610*65536 + 1) / 2) = 6442516480 -> 2^31 - 1.
#[test]
fn subtracting_rules_with_no_level_can_saturate() {
    let windows = [window(0, 0, 3, 1)];
    let background = [32768, 32768, 15];
    for rule in [
        SelectionRule::SubtractNextDistinct,
        SelectionRule::SubtractMean { count: 4 },
    ] {
        let mut cfg = config(3, 1, &windows, rule, 2);
        cfg.calibration.background = Some(&background);
        assert_eq!(
            single(run(&cfg, &[0, 0, 4097])),
            out(0, i32::MAX, 0, 1, true),
            "{rule:?}"
        );
    }
}

fn with_filter(mut cfg: Config<'_>, gain_shift: u8) -> Config<'_> {
    cfg.selection.level_filter = Some(LevelFilter { gain_shift });
    cfg
}

/// 1x3 window (a = -2 0 2), subtract-next N = 1, g = 10, B = 0 0 1.
/// The spot is pixel 0 alone in K each frame, so qx = -2 * 32768 = -65536.
#[test]
fn level_filter_over_three_frames_and_reset() {
    let windows = [window(0, 0, 3, 1)];
    let background = [0, 0, 1];
    let mut cfg = with_filter(config(3, 1, &windows, SelectionRule::SubtractNext, 1), 10);
    cfg.calibration.background = Some(&background);
    let mut reference = Reference::new(&cfg).unwrap();

    // Frame 1: raw 200 70 0 -> p = 3200 1120 -1, l = v(2) = 1120.
    // Not ready: F_s = 256 * 1120 = 286720, L = 1120. w = 2080.
    let frame1 = [200, 70, 0];
    assert_eq!(
        single(reference.process_frame(&frame1).unwrap()),
        out(0, -65536, 0, 2080, true)
    );
    // Frame 2: raw 200 0 6 -> p = 3200 0 95, l = 95.
    // 256*95 - 286720 = -262400; >> 10 = floor(-256.25) = -257 (truncation
    // would give -256). F_s = 286463 = 1118*256 + 255, L = 1118 (1119 with
    // truncation). w = 3200 - 1118 = 2082.
    assert_eq!(
        single(reference.process_frame(&[200, 0, 6]).unwrap()),
        out(0, -65536, 0, 2082, true)
    );
    // Frame 3: raw 1000 326 0 -> p = 16000 5216 -1, l = 5216.
    // 256*5216 - 286463 = 1335296 - 286463 = 1048833; >> 10 = floor(1024.25)
    // = 1024. F_s = 287487 = 1123*256 - 1, L = 1122. w = 16000 - 1122 = 14878.
    assert_eq!(
        single(reference.process_frame(&[1000, 326, 0]).unwrap()),
        out(0, -65536, 0, 14878, true)
    );
    // Reset: frame 1 again starts the filter afresh: L = 1120, w = 2080.
    reference.reset_level_filter();
    assert_eq!(
        single(reference.process_frame(&frame1).unwrap()),
        out(0, -65536, 0, 2080, true)
    );
}

/// With the filtered level, subtract-next keeps `p > v(N+1)` and a kept value
/// below `L` weighs 0. 1x3 window, N = 2, g = 1.
#[test]
fn filtered_level_above_a_kept_value_weighs_zero() {
    let windows = [window(0, 0, 3, 1)];
    let cfg = with_filter(config(3, 1, &windows, SelectionRule::SubtractNext, 2), 1);
    let mut reference = Reference::new(&cfg).unwrap();
    // Frame 1: p = 160 144 128, l = v(3) = 128, F_s = 32768, L = 128.
    // K = {160, 144}, w = 32, 16, 0. F = 48, Sx = -64,
    // qx = floor((-64*65536 + 48) / 96) = floor(-43690.17) = -43691
    assert_eq!(
        single(reference.process_frame(&[10, 9, 8]).unwrap()),
        out(0, -43691, 0, 48, true)
    );
    // Frame 2: p = 160 32 16, l = 16: F_s = 32768 + ((4096 - 32768) >> 1)
    // = 32768 - 14336 = 18432, L = 72. K = p > 16 = {160, 32}:
    // w = 88, max(0, 32 - 72) = 0. F = 88, Sx = -176, qx = -65536.
    assert_eq!(
        single(reference.process_frame(&[10, 2, 1]).unwrap()),
        out(0, -65536, 0, 88, true)
    );
}

/// §4: when `l` is none the state is unchanged and `w_p = p`; a window with
/// `N >= n` is unaffected by the filter. Windows W0 = 1x3 at x = 0 (N = 1),
/// W1 = 1x3 at x = 3 (N = 3 = n); subtract-next-distinct, g = 1.
#[test]
fn level_filter_without_a_level_keeps_its_state() {
    let windows = [window(0, 0, 3, 1), window(3, 0, 3, 1)];
    let counts = [1, 3];
    let mut cfg = with_filter(
        config(6, 1, &windows, SelectionRule::SubtractNextDistinct, 1),
        1,
    );
    cfg.selection.count = PixelCount::PerSubaperture(&counts);
    let mut reference = Reference::new(&cfg).unwrap();

    // Frame 1, both windows p = 160 64 32.
    // W0: l = 64, F_s = 16384, L = 64, w = 96 at a = -2: qx = -65536.
    // W1: w = p: F = 256, Sx = -320 + 64 = -256,
    //     qx = floor((-256*65536 + 256) / 512) = floor(-32767.5) = -32768.
    assert_eq!(
        reference.process_frame(&[10, 4, 2, 10, 4, 2]).unwrap(),
        vec![out(0, -65536, 0, 96, true), out(1, -32768, 0, 256, true)]
    );
    // Frame 2, all p = 48. W0: v(1) = 48, nothing below: l none, state kept,
    // w = p: F = 144, Sx = 48 * (-2 + 0 + 2) = 0, qx = floor(144/288) = 0.
    // W1: the same.
    assert_eq!(
        reference.process_frame(&[3; 6]).unwrap(),
        vec![out(0, 0, 0, 144, true), out(1, 0, 0, 144, true)]
    );
    // Frame 3, p = 160 128 32. W0: l = 128, ready from frame 1:
    // F_s = 16384 + ((32768 - 16384) >> 1) = 24576, L = 96. K = p >= 160,
    // w = 64: qx = -65536. (Had frame 2 reset the filter: L = 128, w = 32.)
    // W1: w = p: F = 320, Sx = -320 + 64 = -256,
    //     qx = floor((-256*65536 + 320) / 640) = floor(-26213.9) = -26214.
    assert_eq!(
        reference.process_frame(&[10, 8, 2, 10, 8, 2]).unwrap(),
        vec![out(0, -65536, 0, 64, true), out(1, -26214, 0, 320, true)]
    );
}

/// Camera 4x2, bit depth 4 (raw <= 15). Windows, with last pixel (row, col):
/// W0 = (0,0,2,1) (0,1); W1 = (2,0,2,2) (1,3); W2 = (0,1,2,1) (1,1);
/// W3 = (0,0,1,2) (1,0). subtract-next N = 1, g = 1.
fn invalid_frame_config(windows: &[SubapertureWindow]) -> Config<'_> {
    let mut cfg = with_filter(config(4, 2, windows, SelectionRule::SubtractNext, 1), 1);
    cfg.camera.bit_depth = 4;
    cfg
}

const INVALID_FRAME_WINDOWS: [SubapertureWindow; 4] = [
    SubapertureWindow {
        x: 0,
        y: 0,
        width: 2,
        height: 1,
    },
    SubapertureWindow {
        x: 2,
        y: 0,
        width: 2,
        height: 2,
    },
    SubapertureWindow {
        x: 0,
        y: 1,
        width: 2,
        height: 1,
    },
    SubapertureWindow {
        x: 0,
        y: 0,
        width: 1,
        height: 2,
    },
];

/// Frame A: rows [15 1 15 1], [1 15 1 1]. Each window has one 240 and
/// otherwise 16: l = 16, w = 224 on one pixel. W0: a = -1; W1: (a, b) =
/// (-1, -1); W2: a = +1; W3: b = -1; so the slopes are +-32768 or 0.
const FRAME_A: [u16; 8] = [15, 1, 15, 1, 1, 15, 1, 1];

fn frame_a_outputs(flux: [i64; 4]) -> Vec<SubapertureOutput> {
    vec![
        out(0, -32768, 0, flux[0], true),
        out(1, -32768, -32768, flux[1], true),
        out(2, 32768, 0, flux[2], true),
        out(3, 0, -32768, flux[3], true),
    ]
}

#[test]
fn completed_before_is_strict_raster_order_of_last_pixels() {
    let cfg = invalid_frame_config(&INVALID_FRAME_WINDOWS);
    let reference = Reference::new(&cfg).unwrap();
    assert_eq!(reference.completed_before(0, 0), Vec::<usize>::new());
    assert_eq!(reference.completed_before(0, 1), Vec::<usize>::new());
    assert_eq!(reference.completed_before(0, 2), vec![0]);
    assert_eq!(reference.completed_before(1, 0), vec![0]);
    assert_eq!(reference.completed_before(1, 1), vec![0, 3]);
    assert_eq!(reference.completed_before(1, 2), vec![0, 2, 3]);
    assert_eq!(reference.completed_before(1, 3), vec![0, 2, 3]);
    assert_eq!(reference.completed_before(2, 0), vec![0, 1, 2, 3]);
}

#[test]
fn invalid_pixel_updates_only_completed_subapertures() {
    let cfg = invalid_frame_config(&INVALID_FRAME_WINDOWS);
    let mut reference = Reference::new(&cfg).unwrap();
    // Frame A: every F_s = 256 * 16 = 4096, w = 224.
    assert_eq!(
        reference.process_frame(&FRAME_A).unwrap(),
        frame_a_outputs([224; 4])
    );
    // Frame B: rows [15 5 15 5], [5 16 5 5]; 16 > 15 at row 1, column 1
    // (and it is the first such pixel).
    let frame_b = [15, 5, 15, 5, 5, 16, 5, 5];
    assert_eq!(
        reference.process_frame(&frame_b),
        Err(FrameError::PixelOutOfRange {
            row: 1,
            column: 1,
            value: 16
        })
    );
    // Completed before (1,1): W0 and W3, each with p = 240, 80: l = 80,
    // F_s = 4096 + ((20480 - 4096) >> 1) = 12288. W1 (last pixel (1,3)) and
    // W2 (last pixel is the invalid one) keep F_s = 4096.
    //
    // Frame A again, l = 16: W0, W3: F_s = 12288 + ((4096 - 12288) >> 1) =
    // 8192, L = 32, w = 208. W1, W2: F_s = 4096, L = 16, w = 224.
    assert_eq!(
        reference.process_frame(&FRAME_A).unwrap(),
        frame_a_outputs([208, 224, 224, 208])
    );
}

#[test]
fn wrong_length_frame_changes_nothing() {
    let cfg = invalid_frame_config(&INVALID_FRAME_WINDOWS);
    let mut reference = Reference::new(&cfg).unwrap();
    reference.process_frame(&FRAME_A).unwrap();
    // Frame B with its bad pixel made valid (every l would be 80 and change
    // every F_s), cut short and made long (with an out-of-range pixel, which
    // the length check comes before).
    let frame_b = [15, 5, 15, 5, 5, 5, 5, 5];
    assert_eq!(
        reference.process_frame(&frame_b[..7]),
        Err(FrameError::WrongLength {
            expected: 8,
            found: 7
        })
    );
    let mut long = frame_b.to_vec();
    long.push(16);
    assert_eq!(
        reference.process_frame(&long),
        Err(FrameError::WrongLength {
            expected: 8,
            found: 9
        })
    );
    // Every F_s still 4096: frame A gives L = 16, w = 224 everywhere.
    assert_eq!(
        reference.process_frame(&FRAME_A).unwrap(),
        frame_a_outputs([224; 4])
    );
}

#[test]
fn new_refuses_an_invalid_configuration() {
    let cfg = config(4, 1, &[], SelectionRule::SubtractNext, 1);
    assert_eq!(
        Reference::new(&cfg).err(),
        Some(ConfigError::NoSubapertures)
    );
    let windows = [window(0, 0, 2, 1)];
    let cfg = with_filter(config(4, 1, &windows, SelectionRule::Threshold, 1), 1);
    assert_eq!(
        Reference::new(&cfg).err(),
        Some(ConfigError::LevelFilterWithoutSubtraction)
    );
}

#[test]
fn frame_errors_display_their_numbers() {
    let e = FrameError::PixelOutOfRange {
        row: 3,
        column: 7,
        value: 4096,
    };
    let text = e.to_string();
    assert!(text.contains("row 3") && text.contains("column 7") && text.contains("4096"));
    let e = FrameError::WrongLength {
        expected: 8,
        found: 9,
    };
    let text = e.to_string();
    assert!(text.contains('8') && text.contains('9'));
    let _: &dyn std::error::Error = &e;
}
