//! Stage 1: calibration of raw pixels (SPEC.md §2).
//!
//! Applied to one run of consecutive pixels of a camera row at a time, one
//! pass per configured step, so each pass is a branch-free loop.

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
    #[inline]
    pub fn calibrate(&self, raw: &[u16], first_pixel: usize, out: &mut [i32]) {
        let out = &mut out[..raw.len()];
        for (o, &r) in out.iter_mut().zip(raw) {
            *o = (r as i32) << 4;
        }
        let pixels = first_pixel..first_pixel + raw.len();
        if let Some(background) = self.calibration.background {
            for (o, &b) in out.iter_mut().zip(&background[pixels.clone()]) {
                *o -= b;
            }
        }
        if let Some(gain) = self.calibration.gain {
            // |d * G| < 2^37: the product needs 64 bits; the shifted result fits 26.
            for (o, &g) in out.iter_mut().zip(&gain[pixels]) {
                *o = ((*o as i64 * g as i64) >> 12) as i32;
            }
        }
        if let Some(threshold) = self.calibration.threshold {
            for o in out.iter_mut() {
                if *o < threshold {
                    *o = 0;
                }
            }
        }
    }
}
