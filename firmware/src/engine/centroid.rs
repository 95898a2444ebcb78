//! Stage 3: centre of gravity and slopes (SPEC.md §5).

use super::calibrate::{value_in_run_unchecked, Steps};
use super::select::Entry;
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
        let [reference_x, reference_y] = self
            .parameters
            .reference_slopes
            .map_or([0, 0], |r| r[index as usize]);
        let (slope_x, slope_y) = slopes_narrow(&moments, width, height, reference_x, reference_y)
            .unwrap_or_else(|| slopes_wide(&moments, width, height, reference_x, reference_y));
        SubapertureResult {
            index,
            slope_x,
            slope_y,
            flux,
            valid: true,
        }
    }
}

/// Both slopes of moments with `1 <= F < 2^22` and `|sum(w i)|`,
/// `|sum(w j)| < 2^29` (a window's usual moments: `|sum(w i)| <= 63 F` for
/// non-negative weights) in 32-bit arithmetic, or `None` (the 64-bit
/// path): `S = 2 sum(w i) - (w - 1) F` then fits 31 bits, and
/// [`quotient_narrow`] the rounded quotient. Every window's result (the
/// engine's and the QEMU floor's) passes here: on Cortex-M4 ~64
/// instructions fewer a window than the 64-bit path's range checks,
/// products and clamps (CANARY 0.25 instructions a pixel, 8x8 windows 1.0).
#[inline(always)]
fn slopes_narrow(
    moments: &Moments,
    width: u16,
    height: u16,
    reference_x: i32,
    reference_y: i32,
) -> Option<(i32, i32)> {
    const BOUND: i64 = 1 << 29;
    let flux = moments.sum_w;
    if !(1..1 << 22).contains(&flux)
        || !(-BOUND..BOUND).contains(&moments.sum_wi)
        || !(-BOUND..BOUND).contains(&moments.sum_wj)
    {
        return None;
    }
    let f = flux as i32;
    // |S| < 2^30 + 63 * 2^22 < 2^31.
    let sum_a = 2 * moments.sum_wi as i32 - (width as i32 - 1) * f;
    let sum_b = 2 * moments.sum_wj as i32 - (height as i32 - 1) * f;
    let slope_x = quotient_narrow(sum_a, f as u32)?.saturating_sub(reference_x);
    let slope_y = quotient_narrow(sum_b, f as u32)?.saturating_sub(reference_y);
    Some((slope_x, slope_y))
}

/// Both slopes in 64-bit arithmetic (flux at least 1): rare, out of line,
/// so that [`slopes_narrow`] keeps its registers.
#[cold]
#[inline(never)]
fn slopes_wide(
    moments: &Moments,
    width: u16,
    height: u16,
    reference_x: i32,
    reference_y: i32,
) -> (i32, i32) {
    let flux = moments.sum_w;
    // Centred half-pixel coordinates a = 2i - (w - 1): S = 2 sum(w i) - (w - 1) F.
    let sum_a = 2 * moments.sum_wi - (width as i64 - 1) * flux;
    let sum_b = 2 * moments.sum_wj - (height as i64 - 1) * flux;
    (
        slope(sum_a, flux, reference_x),
        slope(sum_b, flux, reference_y),
    )
}

/// `floor((s * 2^16 + F) / 2F)` for `1 <= F < 2^22` when `|s / 2F| < 2^14`
/// (else `None`), so that the quotient fits 31 bits: [`long_division`].
#[inline(always)]
fn quotient_narrow(s: i32, flux: u32) -> Option<i32> {
    let (high, low) = long_division(s, flux);
    // -2^14 <= high < 2^14: high 2^16 + low (below 2^17) fits.
    (((high + (1 << 14)) as u32) < 1 << 15).then(|| (high << 16) + low as i32)
}

/// `clamp(floor((s * 2^16 + F) / 2F) - reference)`: round half up of
/// s / 2F pixels in 2^-16 pixel.
#[inline]
fn slope(sum: i64, flux: i64, reference: i32) -> i32 {
    let quotient = rounded_quotient(sum, flux);
    (quotient - reference as i64).clamp(i32::MIN as i64, i32::MAX as i64) as i32
}

/// `floor((sum * 2^16 + flux) / (2 flux))` for `flux >= 1` (SPEC.md §5),
/// for [`slopes_wide`]: with three 32-bit divisions when the operands allow,
/// else [`rounded_quotient_portable`]'s one 64-bit division. Both, and the
/// 32-bit path, are held to §5's arithmetic by `engine_limits`'
/// `slopes_at_the_bounds_of_the_32_bit_path`.
#[inline]
fn rounded_quotient(sum: i64, flux: i64) -> i64 {
    match rounded_quotient_narrow(sum, flux) {
        Some(q) => q,
        None => rounded_quotient_portable(sum, flux),
    }
}

/// The definition of [`rounded_quotient`]: one 64-bit division (a library
/// call of about a hundred instructions on Cortex-M).
#[inline]
fn rounded_quotient_portable(sum: i64, flux: i64) -> i64 {
    ((sum << 16) + flux).div_euclid(2 * flux)
}

/// [`long_division`] when the divisor `2 flux < 2^23` and `|sum| < 2^31`.
#[inline]
fn rounded_quotient_narrow(sum: i64, flux: i64) -> Option<i64> {
    if !(1..1 << 22).contains(&flux) || !(-(1i64 << 31)..1 << 31).contains(&sum) {
        return None;
    }
    let (high, low) = long_division(sum as i32, flux as u32);
    Some(((high as i64) << 16) + low as i64)
}

/// `floor((s * 2^16 + F) / D)` with `D = 2F < 2^23` as `high 2^16 + low`,
/// by long division in base 2^8 with 32-bit hardware division: with
/// `s = high D + ra` (`0 <= ra < D`) and `F = fh 2^8 + fl`,
/// `s 2^16 + F = high D 2^16 + ((ra 2^8 + fh) 2^8 + fl)`, and the inner term
/// is divided in two steps whose dividends stay below 2^32; `low < 2^17`.
#[inline(always)]
fn long_division(s: i32, flux: u32) -> (i32, u32) {
    let d = 2 * flux as i32;
    let (mut high, mut ra) = (s / d, s % d);
    if ra < 0 {
        high -= 1;
        ra += d;
    }
    let d = d as u32;
    let x1 = ((ra as u32) << 8) + (flux >> 8);
    let (qb, rb) = (x1 / d, x1 % d);
    let qc = ((rb << 8) + (flux & 0xff)) / d;
    (high, (qb << 8) + qc)
}

/// Sums over the candidates above a level `u`: `p`, `p i`, `p j`, their
/// number, and `i + 2^16 j` (fewer than 1024 such candidates, so neither
/// half carries). A window's moments at a cutoff `v >= u` follow from them
/// in closed form ([`SumsAbove::moments`]) when no candidate lies between
/// `u` and `v`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SumsAbove {
    pub sum_p: i64,
    pub sum_pi: i64,
    pub sum_pj: i64,
    pub count: u32,
    pub sum_ij: u32,
}

impl SumsAbove {
    pub const NONE: SumsAbove = SumsAbove {
        sum_p: 0,
        sum_pi: 0,
        sum_pj: 0,
        count: 0,
        sum_ij: 0,
    };

    /// The moments of `p - v` over these pixels.
    #[inline(always)]
    pub fn moments(&self, v: i32) -> Moments {
        let v = v as i64;
        Moments {
            sum_w: self.sum_p - v * self.count as i64,
            sum_wi: self.sum_pi - v * (self.sum_ij & 0xffff) as i64,
            sum_wj: self.sum_pj - v * (self.sum_ij >> 16) as i64,
        }
    }
}

/// [`SumsAbove`] over the entries of `entries` above `u`, in one pass:
/// packed positions `(j << 6) | i` (below 4096, as the engine stores
/// them), fewer than 1024 of them above `u`. On Cortex-M an assembly loop
/// of thirteen instructions an entry above `u` (the compiler's, its
/// accumulators short of registers, reloaded `u` from the stack for each);
/// [`sums_above_portable`] is its twin, which the QEMU benchmark's
/// self-test compares it with.
#[inline(always)]
pub fn sums_above(entries: &[Entry], u: i32) -> SumsAbove {
    #[cfg(target_arch = "arm")]
    {
        dsp::sums_above(entries, u)
    }
    #[cfg(not(target_arch = "arm"))]
    {
        sums_above_portable(entries, u)
    }
}

/// The definition of [`sums_above`].
#[inline(never)]
pub fn sums_above_portable(entries: &[Entry], u: i32) -> SumsAbove {
    let mut above = SumsAbove::NONE;
    // Without a branch (an entry's side of `u` mispredicts on hosts): every
    // entry added, times 0 or 1.
    for e in entries {
        let keep = (e.value > u) as u32;
        let (i, j) = (e.position & 63, (e.position >> 6) & 63);
        let p = e.value as i64 * keep as i64;
        above.sum_p += p;
        above.sum_pi += p * i as i64;
        above.sum_pj += p * j as i64;
        above.count += keep;
        above.sum_ij += (i | (j << 16)) * keep;
    }
    above
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
    use super::{Entry, SumsAbove};

    /// What the assembly loop of [`sums_above`] leaves, in its registers'
    /// order: `sum p`, `sum p pos` (`pos = i + 64 j`), `sum p j`,
    /// `count << 16 | sum j`, `sum pos`.
    #[repr(C)]
    struct Raw {
        sum_p: i64,
        sum_p_pos: i64,
        sum_pj: i64,
        count_j: u32,
        sum_pos: u32,
    }

    /// The entry in r3 (value) and r12 (position) added to the sums: the
    /// loop's three copies of it (the first entry of an odd number, and
    /// a pair's two).
    macro_rules! add_above {
        () => {
            concat!(
                "adds r4, r4, r3\n",
                "adc r5, r5, r3, asr #31\n",
                "lsr lr, r12, #6\n",
                "smlal r6, r7, r12, r3\n",
                "smlal r8, r9, lr, r3\n",
                "add r11, r11, r12\n",
                "add r10, r10, lr\n",
            )
        };
    }

    /// r0 the next entry, r1 the end, r2 `u`, r3 a value, r12 its
    /// position, lr its row `j`; r4-r11 the sums of [`Raw`], stored
    /// through the pointer pushed with them. `i` is never extracted:
    /// `sum p i = sum p pos - 64 sum p j` and `sum i = sum pos - 64 sum j`.
    /// The count starts at every entry and loses those at or below `u`
    /// (few, in the closed form's fronts), so that an entry above `u` does
    /// not add to it; two entries a pass (after the first alone if their
    /// number is odd), the entries at or below `u` handled out of line: 11
    /// instructions an entry above `u` instead of 13, 5 below as before.
    #[unsafe(naked)]
    unsafe extern "C" fn sums_above_loop(
        entries: *const Entry,
        end: *const Entry,
        u: i32,
        raw: *mut Raw,
    ) {
        core::arch::naked_asm!(
            "push {{r3-r11, lr}}",
            "movs r4, #0",
            "movs r5, #0",
            "movs r6, #0",
            "movs r7, #0",
            "mov r8, #0",
            "mov r9, #0",
            "mov r11, #0",
            // `count << 16`: the bytes (8 an entry) shifted up 13.
            "subs r10, r1, r0",
            "beq 3f",
            "lsl r10, r10, #13",
            "tst r10, #65536",
            "beq 1f",
            "ldrd r3, r12, [r0], #8",
            "cmp r3, r2",
            "ble 4f",
            add_above!(),
            "5:",
            "cmp r0, r1",
            "beq 3f",
            "1:",
            "ldrd r3, r12, [r0], #8",
            "cmp r3, r2",
            "ble 6f",
            add_above!(),
            "ldrd r3, r12, [r0], #8",
            "cmp r3, r2",
            "ble 8f",
            "7:",
            add_above!(),
            "9:",
            "cmp r0, r1",
            "bne 1b",
            "3:",
            "pop {{r3}}",
            "stm r3, {{r4-r11}}",
            "pop {{r4-r11, pc}}",
            // An entry at or below `u`: one fewer counted (as the pair's
            // first, then its second tested here: no more instructions
            // an entry than the loop without pairs when none is above).
            "4:",
            "sub r10, r10, #65536",
            "b 5b",
            "6:",
            "sub r10, r10, #65536",
            "ldrd r3, r12, [r0], #8",
            "cmp r3, r2",
            "bgt 7b",
            "8:",
            "sub r10, r10, #65536",
            "cmp r0, r1",
            "bne 1b",
            "b 3b",
        )
    }

    #[inline(always)]
    pub fn sums_above(entries: &[Entry], u: i32) -> SumsAbove {
        let mut raw = Raw {
            sum_p: 0,
            sum_p_pos: 0,
            sum_pj: 0,
            count_j: 0,
            sum_pos: 0,
        };
        let range = entries.as_ptr_range();
        // SAFETY: reads the entries of the slice only, writes `raw`.
        unsafe { sums_above_loop(range.start, range.end, u, &mut raw) };
        let sum_j = raw.count_j & 0xffff;
        SumsAbove {
            sum_p: raw.sum_p,
            sum_pi: raw.sum_p_pos - 64 * raw.sum_pj,
            sum_pj: raw.sum_pj,
            count: raw.count_j >> 16,
            sum_ij: (raw.sum_pos - 64 * sum_j) | sum_j << 16,
        }
    }

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
