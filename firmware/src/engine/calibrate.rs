//! Stage 1: calibration of raw pixels (SPEC.md §2).
//!
//! One arithmetic, [`value_in_run`] (the `k`-th pixel of a run, with the
//! run's slices of the maps; [`value_in_run_unchecked`] for the hot
//! loops), which the engine applies only to the pixels that pass its
//! pre-filter: [`raw_floor`] turns a calibrated threshold into the
//! smallest raw value that can reach it in a window, so that raw pixels
//! below it are rejected uncalibrated (by the row kernel as pixels arrive,
//! by [`Calibrator::each_in_range`] when a window is read again).

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

    /// [`raw_floor`] of `threshold` over a window with `bounds`.
    #[inline(always)]
    pub fn raw_floor(&self, bounds: WindowBounds, threshold: i32) -> u32 {
        raw_floor(&self.calibration, bounds, threshold)
    }

    /// Calls `keep(k, p)`, in order, for each pixel `k` of `raw` (pixels
    /// `first_pixel ..` of the frame, row-major index, inside the camera)
    /// whose calibrated value `p` lies in `[low, below)`, until `keep`
    /// returns `false` (then returns `false`). Raw values under `floor`, at
    /// most [`raw_floor`](Self::raw_floor) of `low` for these pixels, are
    /// skipped uncalibrated: a rescan reads a window again for the pixels
    /// its seed left out, and much of a window lies far below them.
    #[inline(always)]
    pub fn each_in_range(
        &self,
        raw: &[u16],
        first_pixel: usize,
        floor: u32,
        range: (i32, i32),
        keep: impl FnMut(usize, i32) -> bool,
    ) -> bool {
        let c = &self.calibration;
        let args = (raw, first_pixel, floor, range);
        match (c.background, c.gain, c.threshold.is_some()) {
            (None, None, false) => each_in_range::<With<false, false, false>>(c, args, keep),
            (None, None, true) => each_in_range::<With<false, false, true>>(c, args, keep),
            (Some(_), None, false) => each_in_range::<With<true, false, false>>(c, args, keep),
            (Some(_), None, true) => each_in_range::<With<true, false, true>>(c, args, keep),
            (None, Some(_), false) => each_in_range::<With<false, true, false>>(c, args, keep),
            (None, Some(_), true) => each_in_range::<With<false, true, true>>(c, args, keep),
            (Some(_), Some(_), false) => each_in_range::<With<true, true, false>>(c, args, keep),
            (Some(_), Some(_), true) => each_in_range::<With<true, true, true>>(c, args, keep),
        }
    }
}

/// [`Calibrator::each_in_range`] with the steps `S`, which are those `c`
/// has: one loop for each combination, without the maps' tests (a value
/// that tested them cost a rescan ~25 instructions a pixel that passed
/// `floor` on Cortex-M4).
#[inline(always)]
fn each_in_range<S: Steps>(
    c: &Calibration<'_>,
    (raw, first_pixel, floor, (low, below)): (&[u16], usize, u32, (i32, i32)),
    mut keep: impl FnMut(usize, i32) -> bool,
) -> bool {
    // SAFETY: `S` holds `c`'s steps (the caller's match), `c` is the
    // engine's validated configuration's and the run lies in the camera
    // (the caller's contract).
    let (background, gain, threshold) = unsafe { run_maps::<S>(c, first_pixel, raw.len()) };
    for (k, &r) in raw.iter().enumerate() {
        if (r as u32) < floor {
            continue;
        }
        // SAFETY: `k < raw.len()`, the length of the maps' runs.
        let p = unsafe { value_in_run_unchecked::<S>(r, k, background, gain, threshold) };
        if p >= low && p < below && !keep(k, p) {
            return false;
        }
    }
    true
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

/// [`raw_floor`] capped at `most` (at most [`FLOOR_NONE`]) for a calibration
/// without gain map or fixed threshold (`plain`: a background map or none),
/// with no test of the calibration: a window's opening takes two
/// (`stream::admission::FreshWindow`), each ~15 instructions fewer on
/// Cortex-M4 this way.
#[inline(always)]
pub fn raw_floor_plain(bounds: WindowBounds, threshold: i32, most: u32) -> u32 {
    // `i32::MIN` (no threshold) stays far below 0: floor 0, as `raw_floor`.
    (floor_without_gain(bounds, threshold).max(0) as u32).min(most)
}

/// `ceil((threshold + min B) / 16)`, unclamped: the raw floor without a gain
/// map. |threshold| < 2^26 (a calibrated value or a level) or `i32::MIN`,
/// |min B| <= 2^20: saturating, the sum keeps its sign.
#[inline(always)]
fn floor_without_gain(bounds: WindowBounds, threshold: i32) -> i32 {
    threshold
        .saturating_add(bounds.background_min)
        .saturating_add(15)
        >> 4
}

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
        return floor_without_gain(bounds, threshold).clamp(0, FLOOR_NONE as i32) as u32;
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
