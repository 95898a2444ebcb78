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
/// maps present in `c`).
#[inline(always)]
fn pass<const BACKGROUND: bool, const GAIN: bool, const THRESHOLD: bool>(
    c: &Calibration<'_>,
    raw: &[u16],
    first_pixel: usize,
    out: &mut [i32],
) {
    let n = raw.len();
    let out = &mut out[..n];
    // Map slices of exactly `n` entries (one bounds check each, per run).
    let background: &[i32] = match c.background {
        Some(map) if BACKGROUND => &map[first_pixel..][..n],
        _ => &[],
    };
    let gain: &[u16] = match c.gain {
        Some(map) if GAIN => &map[first_pixel..][..n],
        _ => &[],
    };
    let threshold = c.threshold.unwrap_or(i32::MIN);
    for k in 0..n {
        // 1. d = 16 r - B   (-2^20 <= d < 2^21)
        let mut d = (raw[k] as i32) << 4;
        if BACKGROUND {
            d -= background[k];
        }
        // 2. |d * G| < 2^37: the product needs 64 bits; the shifted result fits 26.
        if GAIN {
            d = ((d as i64 * gain[k] as i64) >> 12) as i32;
        }
        // 3. threshold
        if THRESHOLD && d < threshold {
            d = 0;
        }
        out[k] = d;
    }
}
