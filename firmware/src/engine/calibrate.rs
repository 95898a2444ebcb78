//! Stage 1: calibration of raw pixels (SPEC.md §2).
//!
//! Two forms of the same arithmetic: [`Calibrator::calibrate`] for a run of
//! consecutive pixels (a branch-free pass, one loop per combination of maps),
//! and [`value`] for one pixel, which the selection's hot loop calls on the
//! few pixels that pass the pre-filter. [`raw_floor`] turns a calibrated
//! threshold into the smallest raw value that can reach it in a window, so
//! that the pre-filter can reject raw pixels without calibrating them.

use brightpix_protocol::{Calibration, Config, SubapertureWindow, GAIN_FRACTION_BITS};

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

/// Which calibration steps a configuration has, as types, so that each
/// combination gets its own hot loop.
pub trait Steps {
    const BACKGROUND: bool;
    const GAIN: bool;
    const THRESHOLD: bool;
}

/// The steps as const parameters.
pub struct With<const BACKGROUND: bool, const GAIN: bool, const THRESHOLD: bool>;

impl<const B: bool, const G: bool, const T: bool> Steps for With<B, G, T> {
    const BACKGROUND: bool = B;
    const GAIN: bool = G;
    const THRESHOLD: bool = T;
}

/// The calibrated value of raw pixel `r` at row-major index `pixel`
/// (SPEC.md §2). The steps in `S` must be those `c` has.
#[inline(always)]
pub fn value<S: Steps>(c: &Calibration<'_>, r: u16, pixel: usize) -> i32 {
    let mut d = (r as i32) << 4;
    if S::BACKGROUND {
        if let Some(background) = c.background {
            d -= background[pixel];
        }
    }
    if S::GAIN {
        if let Some(gain) = c.gain {
            d = ((d as i64 * gain[pixel] as i64) >> GAIN_FRACTION_BITS) as i32;
        }
    }
    if S::THRESHOLD {
        if let Some(threshold) = c.threshold {
            if d < threshold {
                d = 0;
            }
        }
    }
    d
}

/// The calibrated value of raw pixel `r`, the `k`-th of a run whose maps
/// are `background` and `gain` (the run's slices of them; empty when the
/// step is absent) and with the fixed `threshold` (SPEC.md §2).
#[inline(always)]
pub fn value_in_run<S: Steps>(
    r: u16,
    k: usize,
    background: &[i32],
    gain: &[u16],
    threshold: i32,
) -> i32 {
    let mut d = (r as i32) << 4;
    if S::BACKGROUND {
        d -= background[k];
    }
    if S::GAIN {
        d = ((d as i64 * gain[k] as i64) >> GAIN_FRACTION_BITS) as i32;
    }
    if S::THRESHOLD && d < threshold {
        d = 0;
    }
    d
}

/// [`value_in_run`] without bounds checks, for the engine's hot loop.
///
/// # Safety
/// `k < background.len()` if `S::BACKGROUND`, `k < gain.len()` if `S::GAIN`.
#[inline(always)]
pub unsafe fn value_in_run_unchecked<S: Steps>(
    r: u16,
    k: usize,
    background: &[i32],
    gain: &[u16],
    threshold: i32,
) -> i32 {
    let mut d = (r as i32) << 4;
    if S::BACKGROUND {
        // SAFETY: the caller's contract.
        d -= unsafe { *background.get_unchecked(k) };
    }
    if S::GAIN {
        // SAFETY: the caller's contract.
        let g = unsafe { *gain.get_unchecked(k) };
        d = ((d as i64 * g as i64) >> GAIN_FRACTION_BITS) as i32;
    }
    if S::THRESHOLD && d < threshold {
        d = 0;
    }
    d
}

/// A run's slices of the maps `S` uses (empty where a step is absent) and
/// the fixed threshold (`i32::MIN` if absent), for [`value_in_run`]. The
/// steps in `S` must be those `c` has.
///
/// # Safety
/// `pixel + len` is at most the camera's pixel count and `c` belongs to a
/// validated configuration (its maps have a value per camera pixel): the
/// engine's hot path does not check the slices again.
#[inline(always)]
pub(crate) unsafe fn run_maps<'a, S: Steps>(
    c: &Calibration<'a>,
    pixel: usize,
    len: usize,
) -> (&'a [i32], &'a [u16], i32) {
    // SAFETY: the caller's contract.
    let background = match c.background {
        Some(b) if S::BACKGROUND => unsafe { b.get_unchecked(pixel..pixel + len) },
        _ => &[][..],
    };
    let gain = match c.gain {
        Some(g) if S::GAIN => unsafe { g.get_unchecked(pixel..pixel + len) },
        _ => &[][..],
    };
    let threshold = match c.threshold {
        Some(t) if S::THRESHOLD => t,
        _ => i32::MIN,
    };
    (background, gain, threshold)
}

/// What the pre-filter needs to know of a window's calibration maps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WindowBounds {
    /// Smallest background over the window (0 without a map).
    pub background_min: i32,
    /// Largest gain over the window (4096, a gain of 1, without a map).
    pub gain_max: u16,
}

impl WindowBounds {
    pub const NONE: WindowBounds = WindowBounds {
        background_min: 0,
        gain_max: 1 << GAIN_FRACTION_BITS,
    };

    /// The bounds of `window` over `config`'s maps.
    pub fn of(config: &Config<'_>, window: &SubapertureWindow) -> WindowBounds {
        let width = config.camera.width as usize;
        let rows = (window.y as usize..window.y as usize + window.height as usize)
            .map(|y| y * width + window.x as usize..y * width + window.end_column() as usize);
        let c = &config.calibration;
        // Row by row, each a fold without an exit (it vectorises: every
        // engine built computes these for every window).
        WindowBounds {
            background_min: c.background.map_or(0, |b| {
                rows.clone()
                    .map(|run| b[run].iter().fold(i32::MAX, |m, &v| m.min(v)))
                    .fold(i32::MAX, i32::min)
            }),
            gain_max: c.gain.map_or(1 << GAIN_FRACTION_BITS, |g| {
                rows.map(|run| g[run].iter().fold(0, |m, &v| m.max(v)))
                    .fold(0, u16::max)
            }),
        }
    }
}

/// No raw value passes: above any 16-bit pixel.
pub const FLOOR_NONE: u32 = 1 << 16;

/// The smallest raw value that can calibrate to `threshold` or more in a
/// window with `bounds` (0: any; [`FLOOR_NONE`]: none). Conservative: every
/// pixel whose calibrated value is `>= threshold` has `r >= floor`, some
/// below it may too.
///
/// Without a gain map, `16 r - B >= t` needs `16 r >= t + min B`. With
/// one and `t > 0`, `((16 r - B) G) >> 12 >= t` needs `16 r - B > 0` and
/// `(16 r - B) max G >= 4096 t`. A fixed threshold only zeroes values, so
/// it matters only for `t <= 0` (a zeroed pixel, 0, then passes).
pub fn raw_floor(c: &Calibration<'_>, bounds: WindowBounds, threshold: i32) -> u32 {
    if threshold == i32::MIN || (threshold <= 0 && (c.threshold.is_some() || c.gain.is_some())) {
        return 0;
    }
    if c.gain.is_none() {
        // |threshold| < 2^26 past the test above (a calibrated value or a
        // level), |min B| <= 2^20: the sum fits 32 bits.
        let floor = (threshold
            .saturating_add(bounds.background_min)
            .saturating_add(15))
            >> 4;
        return floor.clamp(0, FLOOR_NONE as i32) as u32;
    }
    // threshold > 0 here.
    if bounds.gain_max == 0 {
        return FLOOR_NONE;
    }
    let scaled = (threshold as i64) << GAIN_FRACTION_BITS;
    let needed = (scaled + bounds.gain_max as i64 - 1) / bounds.gain_max as i64;
    // ceil((needed + min B) / 16), floor division by the arithmetic shift.
    let floor = (needed + bounds.background_min as i64 + 15) >> 4;
    floor.clamp(0, FLOOR_NONE as i64) as u32
}
