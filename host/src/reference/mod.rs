//! The reference implementation of `shared/SPEC.md`.
//!
//! It is written from the specification alone, as plainly as possible, so
//! that agreement with the streaming engine means something: the whole frame
//! is in memory, every sub-aperture's calibrated values are fully sorted
//! (descending) every frame, as DARC does, and the rules of SPEC.md §3 are
//! then applied literally from its table. All arithmetic is in `i128`
//! (SPEC.md §7), so no intermediate can overflow; the only narrowing
//! conversions are of the final flux (`|F| < 2^38`, §5) and of the slopes
//! after their saturation (§5).
//!
//! Stages, per frame:
//!
//! 1. [`FrameError`] checks: frame length, then raw pixel range (§1, §8);
//! 2. per sub-aperture, in index order:
//!    - calibrate each pixel of the window (§2),
//!    - select: the kept set `K` and the instantaneous level `l` (§3),
//!    - the level `L` actually subtracted, through the optional level
//!      filter (§4),
//!    - weights `w_p`, then centre of gravity, rounding, reference slopes and
//!      saturation (§5).
//!
//! Speed is not a goal.

use std::fmt;

use brightpix_protocol::{
    Camera, Config, ConfigError, LevelFilter, SelectionRule, SubapertureWindow,
};

/// One sub-aperture's result for one frame (SPEC.md §6).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SubapertureOutput {
    /// Position of the window in the configuration's list.
    pub index: usize,
    /// In 2^-16 pixel; 0 when not valid.
    pub slope_x: i32,
    /// In 2^-16 pixel; 0 when not valid.
    pub slope_y: i32,
    /// `F = sum(w_p)` in 1/16 count, reported even when not valid.
    pub flux: i64,
    /// `F > min_flux`.
    pub valid: bool,
}

/// Why a frame was rejected.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FrameError {
    /// The first raw pixel, in raster order, above `2^bit_depth - 1` (§8).
    PixelOutOfRange { row: u16, column: u16, value: u16 },
    /// The frame does not hold `width * height` pixels.
    WrongLength { expected: usize, found: usize },
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            FrameError::PixelOutOfRange { row, column, value } => write!(
                f,
                "raw pixel at row {row}, column {column} is {value}, above the camera's \
                 largest value 2^bit_depth - 1"
            ),
            FrameError::WrongLength { expected, found } => write!(
                f,
                "frame has {found} pixels, expected {expected} (width x height)"
            ),
        }
    }
}

impl std::error::Error for FrameError {}

/// SPEC.md §4: the state `F_s` (in 2^-8 calibrated units) and `ready_s` of
/// one sub-aperture.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct LevelFilterState {
    f: i128,
    ready: bool,
}

/// The reference processor: an owned copy of the configuration and the
/// level-filter state of every sub-aperture.
#[derive(Clone, Debug)]
pub struct Reference {
    camera: Camera,
    windows: Vec<SubapertureWindow>,
    /// `B`, 1/16 count, full frame.
    background: Option<Vec<i32>>,
    /// `G`, 1/4096, full frame.
    gain: Option<Vec<u16>>,
    /// `T`, 1/16 count.
    threshold: Option<i32>,
    rule: SelectionRule,
    /// `N` of each sub-aperture.
    pixels_to_select: Vec<u16>,
    level_filter: Option<LevelFilter>,
    /// `(rx, ry)` of each sub-aperture, 2^-16 pixel.
    reference_slopes: Option<Vec<[i32; 2]>>,
    /// 1/16 count.
    min_flux: i64,
    level_state: Vec<LevelFilterState>,
}

impl Reference {
    /// Validates `config` and copies what the arithmetic needs. The level
    /// filter starts reset (§4: a configuration is applied).
    pub fn new(config: &Config<'_>) -> Result<Self, ConfigError> {
        config.validate()?;
        let count = config.windows.len();
        Ok(Reference {
            camera: config.camera,
            windows: config.windows.to_vec(),
            background: config.calibration.background.map(<[i32]>::to_vec),
            gain: config.calibration.gain.map(<[u16]>::to_vec),
            threshold: config.calibration.threshold,
            rule: config.selection.rule,
            pixels_to_select: (0..count).map(|s| config.pixel_count(s)).collect(),
            level_filter: config.selection.level_filter,
            reference_slopes: config.centroid.reference_slopes.map(<[[i32; 2]]>::to_vec),
            min_flux: config.centroid.min_flux,
            level_state: vec![LevelFilterState::default(); count],
        })
    }

    /// §4: "a reset is requested": every `ready_s = false`.
    pub fn reset_level_filter(&mut self) {
        self.level_state = vec![LevelFilterState::default(); self.windows.len()];
    }

    /// Processes one frame (raw pixels, raster order). On success, one output
    /// per window, in sub-aperture index order.
    ///
    /// A frame of the wrong length is refused before anything else, with no
    /// state change. A frame with a raw pixel above `2^bit_depth - 1` is
    /// refused naming the first such pixel in raster order; as a streaming
    /// engine would (§4, §8), the sub-apertures completed strictly before that
    /// pixel (see [`Reference::completed_before`]) are processed, which
    /// updates their level-filter state, and the others are left as they
    /// were. Their outputs are not returned; they are those of any frame with
    /// the same pixels in their windows.
    pub fn process_frame(&mut self, frame: &[u16]) -> Result<Vec<SubapertureOutput>, FrameError> {
        let expected = self.camera.pixel_count();
        if frame.len() != expected {
            return Err(FrameError::WrongLength {
                expected,
                found: frame.len(),
            });
        }
        let max_raw = self.camera.max_raw();
        if let Some(position) = frame.iter().position(|&r| r > max_raw) {
            let width = self.camera.width as usize;
            let row = (position / width) as u16;
            let column = (position % width) as u16;
            for s in self.completed_before(row, column) {
                // Only for the §4 state: the engine emitted these outputs.
                let _ = self.process_subaperture(frame, s);
            }
            return Err(FrameError::PixelOutOfRange {
                row,
                column,
                value: frame[position],
            });
        }
        Ok((0..self.windows.len())
            .map(|s| self.process_subaperture(frame, s))
            .collect())
    }

    /// The sub-apertures whose window's last pixel (row `y + h - 1`, column
    /// `x + w - 1`) comes strictly before (`row`, `column`) in raster order,
    /// in index order. These are the ones a streaming engine has completed
    /// (and emitted) when it stops at an invalid pixel at (`row`, `column`).
    pub fn completed_before(&self, row: u16, column: u16) -> Vec<usize> {
        self.windows
            .iter()
            .enumerate()
            .filter(|(_, w)| {
                let last_pixel = (w.y + w.height - 1, w.x + w.width - 1);
                // Tuples compare row first, then column: raster order.
                last_pixel < (row, column)
            })
            .map(|(s, _)| s)
            .collect()
    }

    /// Which pixels of sub-aperture `s`'s window are in §3's kept set `K`
    /// for `frame`, in the window's raster order (all of them when `N >= n`:
    /// no selection). For display only (the live view): the level filter's
    /// state is neither read nor changed, since `K` does not depend on it.
    /// `None` when `s` is not a sub-aperture or `frame` is not
    /// `width x height` pixels.
    pub fn kept_pixels(&self, frame: &[u16], s: usize) -> Option<Vec<bool>> {
        let window = *self.windows.get(s)?;
        if frame.len() != self.camera.pixel_count() {
            return None;
        }
        let values: Vec<i128> = self
            .calibrate_window(frame, window)
            .iter()
            .map(|px| px.p)
            .collect();
        let n_select = self.pixels_to_select[s] as usize;
        Some(match select(self.rule, n_select, &values) {
            None => vec![true; values.len()],
            Some(selection) => values.iter().map(|&p| selection.kept.contains(p)).collect(),
        })
    }

    /// All stages for sub-aperture `s` of a frame whose pixels are in range.
    fn process_subaperture(&mut self, frame: &[u16], s: usize) -> SubapertureOutput {
        let window = self.windows[s];
        let pixels = self.calibrate_window(frame, window);
        let n_select = self.pixels_to_select[s] as usize;
        let values: Vec<i128> = pixels.iter().map(|px| px.p).collect();
        let weights: Vec<i128> = match select(self.rule, n_select, &values) {
            // §3 "No selection": w_p = p, nothing subtracted, no §4 update.
            None => values.clone(),
            Some(selection) => {
                let level = self.level_to_subtract(s, selection.level);
                values
                    .iter()
                    .map(|&p| weight(&selection.kept, level, p))
                    .collect()
            }
        };
        let reference = match &self.reference_slopes {
            Some(list) => list[s],
            None => [0, 0],
        };
        centre_of_gravity(s, window, &pixels, &weights, self.min_flux, reference)
    }

    /// §2 for every pixel of sub-aperture `s`'s window, in raster order
    /// (`frame` a whole camera frame).
    pub fn calibrated(&self, frame: &[u16], s: usize) -> Vec<i128> {
        self.calibrate_window(frame, self.windows[s])
            .into_iter()
            .map(|pixel| pixel.p)
            .collect()
    }

    /// §2 for every pixel of `window`.
    fn calibrate_window(&self, frame: &[u16], window: SubapertureWindow) -> Vec<WindowPixel> {
        let mut pixels = Vec::with_capacity(window.pixel_count());
        for j in 0..window.height {
            for i in 0..window.width {
                let column = (window.x + i) as usize;
                let row = (window.y + j) as usize;
                pixels.push(WindowPixel {
                    i: i as i128,
                    j: j as i128,
                    p: self.calibrate(frame, row, column),
                });
            }
        }
        pixels
    }

    /// §2: the calibrated value `p` of the camera pixel at (`row`, `column`).
    fn calibrate(&self, frame: &[u16], row: usize, column: usize) -> i128 {
        let index = row * self.camera.width as usize + column;
        let r = frame[index] as i128;
        let b = match &self.background {
            Some(map) => map[index] as i128,
            None => 0,
        };
        // 1. d = 16 * r - B
        let mut d = 16 * r - b;
        // 2. d = (d * G) >> 12
        if let Some(map) = &self.gain {
            d = shift_right(d * map[index] as i128, 12);
        }
        // 3. d = 0 if d < T
        if let Some(t) = self.threshold {
            if d < t as i128 {
                d = 0;
            }
        }
        d
    }

    /// §3/§4: the level `L` to subtract, given the instantaneous level `l`,
    /// updating sub-aperture `s`'s filter state when there is a filter.
    /// Called only when there is a selection (`N < n`).
    fn level_to_subtract(&mut self, s: usize, l: Option<i128>) -> Option<i128> {
        let Some(filter) = self.level_filter else {
            // §3: "the level used is L = l".
            return l;
        };
        // §4: "if ... l is none: the state is unchanged and L = none".
        let l = l?;
        let state = &mut self.level_state[s];
        if !state.ready {
            state.f = 256 * l;
            state.ready = true;
        } else {
            state.f += shift_right(256 * l - state.f, filter.gain_shift as u32);
        }
        Some(shift_right(state.f, 8))
    }
}

/// A calibrated pixel of a window at local column `i`, row `j`.
#[derive(Clone, Copy, Debug)]
struct WindowPixel {
    i: i128,
    j: i128,
    p: i128,
}

/// §3's kept set `K`, as a condition on `p`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum KeptSet {
    /// `p >= v(N)`.
    AtLeast(i128),
    /// `p > v(N+1)`.
    Above(i128),
}

impl KeptSet {
    fn contains(self, p: i128) -> bool {
        match self {
            KeptSet::AtLeast(v) => p >= v,
            KeptSet::Above(v) => p > v,
        }
    }
}

/// §3, `N < n`: the kept set and the instantaneous level (`None` = none).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Selection {
    kept: KeptSet,
    level: Option<i128>,
}

/// §3 for one window's calibrated values. `None` when `N >= n` ("No
/// selection").
fn select(rule: SelectionRule, n_select: usize, values: &[i128]) -> Option<Selection> {
    if n_select >= values.len() {
        return None;
    }
    // Full sort, descending; duplicates kept. v(k) = sorted[k - 1].
    let mut sorted = values.to_vec();
    sorted.sort_unstable_by(|a, b| b.cmp(a));
    let v = |k: usize| sorted[k - 1];
    let v_n = v(n_select);
    // Descending, so the values strictly below v(N) are a suffix, and its
    // first entries are the largest of them.
    let below_v_n: Vec<i128> = sorted.iter().copied().filter(|&p| p < v_n).collect();
    let selection = match rule {
        SelectionRule::Threshold => Selection {
            kept: KeptSet::AtLeast(v_n),
            level: None,
        },
        SelectionRule::SubtractNext => Selection {
            kept: KeptSet::Above(v(n_select + 1)),
            level: Some(v(n_select + 1)),
        },
        SelectionRule::SubtractNextDistinct => Selection {
            kept: KeptSet::AtLeast(v_n),
            // The largest value < v(N); none if no pixel is below v(N).
            level: below_v_n.first().copied(),
        },
        SelectionRule::SubtractMean { count: m } => {
            let largest_below = &below_v_n[..below_v_n.len().min(m as usize)];
            let c = largest_below.len() as i128;
            let level = if c == 0 {
                None
            } else {
                Some(floor_div(largest_below.iter().sum(), c))
            };
            Selection {
                kept: KeptSet::AtLeast(v_n),
                level,
            }
        }
    };
    Some(selection)
}

/// §3: the weight of a pixel of value `p`, given the kept set and the level
/// `L` actually subtracted (`None` = none).
fn weight(kept: &KeptSet, level: Option<i128>, p: i128) -> i128 {
    if !kept.contains(p) {
        return 0;
    }
    match level {
        Some(l) => (p - l).max(0),
        None => p,
    }
}

/// §5: flux, validity, rounded slopes, reference slopes, saturation.
fn centre_of_gravity(
    index: usize,
    window: SubapertureWindow,
    pixels: &[WindowPixel],
    weights: &[i128],
    min_flux: i64,
    reference: [i32; 2],
) -> SubapertureOutput {
    let w = window.width as i128;
    let h = window.height as i128;
    let mut flux = 0i128;
    let mut sx = 0i128;
    let mut sy = 0i128;
    for (px, &wp) in pixels.iter().zip(weights) {
        let a = 2 * px.i - (w - 1);
        let b = 2 * px.j - (h - 1);
        flux += wp;
        sx += wp * a;
        sy += wp * b;
    }
    let valid = flux > min_flux as i128;
    let (slope_x, slope_y) = if valid {
        (slope(sx, flux, reference[0]), slope(sy, flux, reference[1]))
    } else {
        (0, 0)
    };
    SubapertureOutput {
        index,
        slope_x,
        slope_y,
        flux: i64::try_from(flux).expect("SPEC.md §5: |F| < 2^38"),
        valid,
    }
}

/// §5: `clamp(floor((S * 2^16 + F) / (2F)) - r, -2^31, 2^31 - 1)`, `F >= 1`.
fn slope(s: i128, flux: i128, reference: i32) -> i32 {
    let q = floor_div(s * (1 << 16) + flux, 2 * flux);
    let saturated = (q - reference as i128).clamp(i32::MIN as i128, i32::MAX as i128);
    saturated as i32
}

/// `floor(a / b)` for `b > 0`: rounds toward minus infinity (SPEC.md
/// notation).
fn floor_div(a: i128, b: i128) -> i128 {
    assert!(b > 0, "floor_div needs a positive divisor");
    let q = a / b; // rounds toward zero
    if a % b != 0 && a < 0 {
        q - 1
    } else {
        q
    }
}

/// `a >> s` of SPEC.md: `floor(a / 2^s)`.
fn shift_right(a: i128, s: u32) -> i128 {
    floor_div(a, 1i128 << s)
}

#[cfg(test)]
mod tests;
