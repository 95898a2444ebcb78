//! Stage 3: centre of gravity and slopes (SPEC.md §5).

use super::calibrate::{value_in_run_unchecked, Steps};
use brightpix_protocol::Centroid;

/// Weighted sums over a window in window-local pixel indices:
/// `sum(w)`, `sum(w * i)`, `sum(w * j)`. |w| < 2^26, n <= 4096, i, j < 64, so
/// each sum fits in 45 bits.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Moments {
    pub sum_w: i64,
    pub sum_wi: i64,
    pub sum_wj: i64,
}

impl Moments {
    pub const ZERO: Moments = Moments {
        sum_w: 0,
        sum_wi: 0,
        sum_wj: 0,
    };

    #[inline(always)]
    pub fn add(&mut self, weight: i32, i: u16, j: u16) {
        let w = weight as i64;
        self.sum_w += w;
        self.sum_wi += w * i as i64;
        self.sum_wj += w * j as i64;
    }

    /// `count` pixels of the same weight with coordinate sums `sum_i`, `sum_j`.
    pub fn add_group(&mut self, weight: i32, count: u16, sum_i: u32, sum_j: u32) {
        let w = weight as i64;
        self.sum_w += w * count as i64;
        self.sum_wi += w * sum_i as i64;
        self.sum_wj += w * sum_j as i64;
    }

    /// A row segment of raw pixels with weight = calibrated value (no
    /// selection): columns `i0..`, row `j`; `background`, `gain` and
    /// `threshold` as `calibrate::value_in_run` takes them, covering `raw`.
    /// One pass: each pixel calibrated and summed. The first moment without
    /// a multiply per pixel: with prefix sums `S_k = p_0 + .. + p_k` and
    /// `S = S_(n-1)`, `sum_k S_k = sum_k p_k (n - k)`, so `sum_k k p_k = n S -
    /// sum_k S_k`.
    #[inline(always)]
    pub fn add_raw_row<S: Steps>(
        &mut self,
        raw: &[u16],
        background: &[i32],
        gain: &[u16],
        threshold: i32,
        i0: u16,
        j: u16,
    ) {
        assert!(
            (!S::BACKGROUND || background.len() >= raw.len())
                && (!S::GAIN || gain.len() >= raw.len())
        );
        // |S_k| <= 64 (2^25 - 1) < 2^31 (a segment is at most 64 pixels).
        let (prefix, prefix_sum) = if S::BACKGROUND && !S::GAIN && !S::THRESHOLD {
            // SAFETY: the map covers the segment (asserted).
            unsafe { prefix_sums_background(raw, background) }
        } else {
            let mut prefix = 0i32;
            let mut prefix_sum = 0i64;
            for (k, &r) in raw.iter().enumerate() {
                // SAFETY: k < raw.len(), which the maps cover (asserted).
                prefix += unsafe { value_in_run_unchecked::<S>(r, k, background, gain, threshold) };
                prefix_sum += prefix as i64;
            }
            (prefix, prefix_sum)
        };
        let sum = prefix as i64;
        let n = raw.len() as i64;
        self.sum_w += sum;
        self.sum_wi += i0 as i64 * sum + (n * sum - prefix_sum);
        self.sum_wj += sum * j as i64;
    }
}

/// One sub-aperture's output for one frame (SPEC.md §6).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SubapertureResult {
    /// Position in the configuration's window list.
    pub index: u16,
    /// Slopes in 2^-16 pixel, reference slopes subtracted; 0 when invalid.
    pub slope_x: i32,
    pub slope_y: i32,
    /// Sum of weights, 1/16 count.
    pub flux: i64,
    pub valid: bool,
}

/// Turns moments into slopes.
#[derive(Clone, Copy, Debug)]
pub struct Centroider<'a> {
    parameters: Centroid<'a>,
}

impl<'a> Centroider<'a> {
    pub fn new(parameters: Centroid<'a>) -> Self {
        Centroider { parameters }
    }

    pub fn result(
        &self,
        index: u16,
        moments: Moments,
        width: u16,
        height: u16,
    ) -> SubapertureResult {
        let flux = moments.sum_w;
        if flux <= self.parameters.min_flux {
            return SubapertureResult {
                index,
                slope_x: 0,
                slope_y: 0,
                flux,
                valid: false,
            };
        }
        // Centred half-pixel coordinates a = 2i - (w - 1): S = 2 sum(w i) - (w - 1) F.
        let sum_a = 2 * moments.sum_wi - (width as i64 - 1) * flux;
        let sum_b = 2 * moments.sum_wj - (height as i64 - 1) * flux;
        let [reference_x, reference_y] = self
            .parameters
            .reference_slopes
            .map_or([0, 0], |r| r[index as usize]);
        SubapertureResult {
            index,
            slope_x: slope(sum_a, flux, reference_x),
            slope_y: slope(sum_b, flux, reference_y),
            flux,
            valid: true,
        }
    }
}

/// `clamp(floor((s * 2^16 + F) / 2F) - reference)`: round half up of
/// s / 2F pixels in 2^-16 pixel.
#[inline]
fn slope(sum: i64, flux: i64, reference: i32) -> i32 {
    let quotient = rounded_quotient(sum, flux);
    (quotient - reference as i64).clamp(i32::MIN as i64, i32::MAX as i64) as i32
}

/// `floor((sum * 2^16 + flux) / (2 flux))` for `flux >= 1` (SPEC.md §5):
/// with three 32-bit divisions when the operands allow (almost always), a
/// 64-bit division otherwise. [`rounded_quotient_portable`] is its twin.
#[inline]
pub fn rounded_quotient(sum: i64, flux: i64) -> i64 {
    match rounded_quotient_narrow(sum, flux) {
        Some(q) => q,
        None => rounded_quotient_portable(sum, flux),
    }
}

/// The definition of [`rounded_quotient`]: one 64-bit division (a library
/// call of about a hundred instructions on Cortex-M).
#[inline]
pub fn rounded_quotient_portable(sum: i64, flux: i64) -> i64 {
    ((sum << 16) + flux).div_euclid(2 * flux)
}

/// Long division in base 2^8 with 32-bit hardware division, when the
/// divisor `D = 2 flux < 2^23` and `|sum| < 2^31`: with `sum = qa D + ra`
/// (`0 <= ra < D`) and `flux = fh 2^8 + fl`,
/// `sum 2^16 + flux = qa D 2^16 + ((ra 2^8 + fh) 2^8 + fl)`, and the inner
/// term is divided in two steps whose dividends stay below 2^32.
#[inline]
fn rounded_quotient_narrow(sum: i64, flux: i64) -> Option<i64> {
    let divisor = 2 * flux;
    if !(1..1 << 23).contains(&divisor) || !(-(1i64 << 31)..1 << 31).contains(&sum) {
        return None;
    }
    let (d, s, f) = (divisor as i32, sum as i32, flux as u32);
    let (mut qa, mut ra) = (s / d, s % d);
    if ra < 0 {
        qa -= 1;
        ra += d;
    }
    let d = d as u32;
    let x1 = ((ra as u32) << 8) + (f >> 8);
    let (qb, rb) = (x1 / d, x1 % d);
    let qc = ((rb << 8) + (f & 0xff)) / d;
    Some(((qa as i64) << 16) + ((qb as i64) << 8) + qc as i64)
}

/// For a segment calibrated with a background map only: the sum of the
/// calibrated values `p_k = 16 r_k - B_k` and the sum of their prefix sums
/// (`S_k = p_0 + .. + p_k`; see [`Moments::add_raw_row`]). On Cortex-M, for a
/// word-aligned segment of whole words, two pixels in fourteen
/// instructions (assembly); [`prefix_sums_background_portable`] is its
/// twin, which the QEMU benchmark's self-test compares it with.
///
/// # Safety
/// `background` holds at least `raw.len()` values.
#[inline(always)]
pub unsafe fn prefix_sums_background(raw: &[u16], background: &[i32]) -> (i32, i64) {
    #[cfg(target_arch = "arm")]
    if (raw.as_ptr() as usize | raw.len()) & 1 == 0
        && raw.as_ptr() as usize & 2 == 0
        && !raw.is_empty()
    {
        // SAFETY: aligned whole words (checked); the caller's contract for
        // the background.
        return unsafe { dsp::prefix_sums_background(raw, background) };
    }
    prefix_sums_background_portable(raw, background)
}

/// The definition of [`prefix_sums_background`].
pub fn prefix_sums_background_portable(raw: &[u16], background: &[i32]) -> (i32, i64) {
    let mut prefix = 0i32;
    let mut prefix_sum = 0i64;
    for (&r, &b) in raw.iter().zip(background) {
        prefix = prefix.wrapping_add(((r as i32) << 4) - b);
        prefix_sum += prefix as i64;
    }
    (prefix, prefix_sum)
}

#[cfg(target_arch = "arm")]
mod dsp {
    /// [`super::prefix_sums_background`] for `raw` word-aligned, of even,
    /// non-zero length.
    ///
    /// # Safety
    /// As there, and `raw` as said.
    #[inline(always)]
    pub unsafe fn prefix_sums_background(raw: &[u16], background: &[i32]) -> (i32, i64) {
        let (mut prefix, mut low, mut high) = (0i32, 0u32, 0u32);
        // SAFETY: reads the raw words and as many background values, as
        // the caller's contract allows; registers only otherwise.
        unsafe {
            core::arch::asm!(
                "2:",
                "ldr {w}, [{p}], #4",
                "ldrd {b0}, {b1}, [{b}], #8",
                "uxth {t}, {w}",
                "rsb {t}, {b0}, {t}, lsl #4",
                "add {s}, {s}, {t}",
                "adds {lo}, {lo}, {s}",
                "adc {hi}, {hi}, {s}, asr #31",
                "lsrs {t}, {w}, #16",
                "rsb {t}, {b1}, {t}, lsl #4",
                "add {s}, {s}, {t}",
                "adds {lo}, {lo}, {s}",
                "adc {hi}, {hi}, {s}, asr #31",
                "cmp {p}, {e}",
                "bne 2b",
                p = inout(reg) raw.as_ptr() => _,
                e = in(reg) raw.as_ptr().add(raw.len()),
                b = inout(reg) background.as_ptr() => _,
                w = out(reg) _,
                b0 = out(reg) _,
                b1 = out(reg) _,
                t = out(reg) _,
                s = inout(reg) prefix,
                lo = inout(reg) low,
                hi = inout(reg) high,
                options(nostack, readonly),
            );
        }
        (prefix, ((high as u64) << 32 | low as u64) as i64)
    }
}
