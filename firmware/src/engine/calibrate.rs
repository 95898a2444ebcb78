//! Stage 1: calibration of raw pixels (SPEC.md §2).
//!
//! Applied to one run of consecutive pixels of a camera row at a time, in a
//! single branch-free pass: the configured steps are chosen once per run, and
//! each combination of maps has its own loop.

use brightpix_protocol::Calibration;

/// The calibration maps and threshold of a configuration.
#[derive(Clone, Copy, Debug)]
pub struct Calibrator<'a> {
    calibration: Calibration<'a>,
}

impl<'a> Calibrator<'a> {
    pub fn new(calibration: Calibration<'a>) -> Self {
        Calibrator { calibration }
    }

    /// Calibrates `raw` (pixels `first_pixel ..` of the frame, row-major
    /// index) into `out[..raw.len()]`, in 1/16 count.
    ///
    /// Not inlined: one copy of the eight loops serves all rules (inlined
    /// into each rule's routing loop they made the engine's Cortex-M7 code
    /// about 6 times larger), and the engine calls it once per block of a
    /// row, not per window.
    #[inline(never)]
    pub fn calibrate(&self, raw: &[u16], first_pixel: usize, out: &mut [i32]) {
        let c = &self.calibration;
        match (c.background, c.gain, c.threshold.is_some()) {
            (None, None, false) => pass::<false, false, false>(c, raw, first_pixel, out),
            (None, None, true) => pass::<false, false, true>(c, raw, first_pixel, out),
            (Some(_), None, false) => pass::<true, false, false>(c, raw, first_pixel, out),
            (Some(_), None, true) => pass::<true, false, true>(c, raw, first_pixel, out),
            (None, Some(_), false) => pass::<false, true, false>(c, raw, first_pixel, out),
            (None, Some(_), true) => pass::<false, true, true>(c, raw, first_pixel, out),
            (Some(_), Some(_), false) => pass::<true, true, false>(c, raw, first_pixel, out),
            (Some(_), Some(_), true) => pass::<true, true, true>(c, raw, first_pixel, out),
        }
    }
}

/// One pass doing the steps selected by the flags (which must match the
/// maps present in `c`), written as zipped iterators over exactly `n`
/// entries of each slice, so that the loop walks pointers without bounds
/// checks.
#[inline(always)]
fn pass<const BACKGROUND: bool, const GAIN: bool, const THRESHOLD: bool>(
    c: &Calibration<'_>,
    raw: &[u16],
    first_pixel: usize,
    out: &mut [i32],
) {
    let n = raw.len();
    let out = &mut out[..n];
    let threshold = c.threshold.unwrap_or(i32::MIN);
    // 1. d = 16 r - B   (-2^20 <= d < 2^21)
    let shifted = raw.iter().map(|&r| (r as i32) << 4);
    // 2. |d * G| < 2^37: the product needs 64 bits; the shifted result fits 26.
    let gained = |d: i32, g: u16| ((d as i64 * g as i64) >> 12) as i32;
    match (c.background, c.gain) {
        (Some(background), Some(gain)) if BACKGROUND && GAIN => {
            let maps = background[first_pixel..][..n]
                .iter()
                .zip(&gain[first_pixel..][..n]);
            let d = shifted.zip(maps).map(|(d, (&b, &g))| gained(d - b, g));
            store::<THRESHOLD>(out, d, threshold)
        }
        (Some(background), _) if BACKGROUND => {
            let d = shifted
                .zip(&background[first_pixel..][..n])
                .map(|(d, &b)| d - b);
            store::<THRESHOLD>(out, d, threshold)
        }
        (_, Some(gain)) if GAIN => {
            let d = shifted
                .zip(&gain[first_pixel..][..n])
                .map(|(d, &g)| gained(d, g));
            store::<THRESHOLD>(out, d, threshold)
        }
        _ => store::<THRESHOLD>(out, shifted, threshold),
    }
}

/// 3. threshold, and the store.
#[inline(always)]
fn store<const THRESHOLD: bool>(
    out: &mut [i32],
    values: impl Iterator<Item = i32>,
    threshold: i32,
) {
    for (o, d) in out.iter_mut().zip(values) {
        *o = if THRESHOLD && d < threshold { 0 } else { d };
    }
}
