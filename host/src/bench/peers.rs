//! The alternatives a user could pick instead of the engine, each written as
//! well as we can, run on the same frames in the same run:
//!
//! - [`SortPeer`]: the paper's method in the engine's arithmetic (SPEC.md):
//!   calibrate a window into `i32`, sort a copy (`sort_unstable`), read the
//!   rule's level off the sorted values, centre of gravity in integers. Any
//!   rule, per-sub-aperture N and the level filter: its results must equal
//!   the engine's exactly.
//! - [`FloatPeer`] in three flavours of DARC's method (subtract-next-distinct
//!   in `f32`: a float copy of the window, `v(N)`, the largest value below
//!   it, centre of gravity in `f32`): [`Selector::Sort`] (DARC as flown: a
//!   full quicksort, here `sort_unstable_by`, a pattern-defeating quicksort),
//!   [`Selector::NthElement`] (`select_nth_unstable_by`, C++'s
//!   `nth_element`: introselect) and [`Selector::BranchFree`] (a quickselect
//!   whose partition loops have no data-dependent branch: the strongest we
//!   could write, and on x86 the one to beat). Their slopes must be within
//!   2^-16 pixel of the engine's with the `subtract-next-distinct` rule.
//!
//! Every peer calibrates per SPEC.md §2 (background, gain, threshold) before
//! its float copy, so that the selections are of the same values; that is
//! one multiply-subtract per pixel, as in DARC.

use brightpix_firmware::engine::centroid::{Centroider, Moments};
use brightpix_firmware::engine::{LevelFilterState, SubapertureResult};
use brightpix_protocol::{Config, SelectionRule, SubapertureWindow};

/// One sub-aperture's slopes from a peer, in pixels, reference slopes
/// subtracted; 0 when invalid.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PeerSlope {
    pub x: f64,
    pub y: f64,
    pub valid: bool,
}

/// A method that turns a frame into slopes.
pub trait Peer: Send {
    /// Short name for tables.
    fn name(&self) -> &'static str;
    /// Processes one camera frame into `out`, one entry per sub-aperture.
    fn process(&mut self, frame: &[u16], out: &mut [PeerSlope]);
}

/// SPEC.md §2 for the peers: the windows and maps of a configuration.
struct Calibration {
    windows: Vec<SubapertureWindow>,
    width: usize,
    background: Option<Vec<i32>>,
    gain: Option<Vec<u16>>,
    threshold: Option<i32>,
    counts: Vec<u16>,
}

impl Calibration {
    fn new(config: &Config<'_>) -> Self {
        Calibration {
            windows: config.windows.to_vec(),
            width: config.camera.width as usize,
            background: config.calibration.background.map(<[i32]>::to_vec),
            gain: config.calibration.gain.map(<[u16]>::to_vec),
            threshold: config.calibration.threshold,
            counts: (0..config.windows.len())
                .map(|k| config.pixel_count(k))
                .collect(),
        }
    }

    fn largest_window(&self) -> usize {
        self.windows
            .iter()
            .map(SubapertureWindow::pixel_count)
            .max()
            .unwrap_or(0)
    }

    /// Window `k`'s calibrated values, row-major, into `out`; each value
    /// also goes through `map` (identity, or a float conversion).
    #[inline]
    fn window<T>(&self, frame: &[u16], k: usize, out: &mut [T], map: impl Fn(i32) -> T) {
        let w = self.windows[k];
        let (x, y, width) = (w.x as usize, w.y as usize, w.width as usize);
        for j in 0..w.height as usize {
            let at = (y + j) * self.width + x;
            let raw = &frame[at..at + width];
            let out = &mut out[j * width..(j + 1) * width];
            match (&self.background, &self.gain, self.threshold) {
                (Some(b), None, None) => {
                    for ((o, &r), &b) in out.iter_mut().zip(raw).zip(&b[at..at + width]) {
                        *o = map(((r as i32) << 4) - b);
                    }
                }
                (None, None, None) => {
                    for (o, &r) in out.iter_mut().zip(raw) {
                        *o = map((r as i32) << 4);
                    }
                }
                (background, gain, threshold) => {
                    for (i, (o, &r)) in out.iter_mut().zip(raw).enumerate() {
                        let mut d =
                            ((r as i32) << 4) - background.as_ref().map_or(0, |b| b[at + i]);
                        if let Some(g) = gain {
                            d = ((d as i64 * g[at + i] as i64) >> 12) as i32;
                        }
                        if threshold.is_some_and(|t| d < t) {
                            d = 0;
                        }
                        *o = map(d);
                    }
                }
            }
        }
    }
}

/// The paper's method in the engine's arithmetic: sort per window.
pub struct SortPeer<'c> {
    calibration: Calibration,
    rule: SelectionRule,
    gain_shift: Option<u8>,
    filters: Vec<LevelFilterState>,
    centroider: Centroider<'c>,
    values: Vec<i32>,
    sorted: Vec<i32>,
    /// The last frame's exact results (for the agreement check).
    pub results: Vec<SubapertureResult>,
}

impl<'c> SortPeer<'c> {
    pub fn new(config: &Config<'c>) -> Self {
        let calibration = Calibration::new(config);
        let largest = calibration.largest_window();
        SortPeer {
            rule: config.selection.rule,
            gain_shift: config.selection.level_filter.map(|f| f.gain_shift),
            filters: vec![LevelFilterState::RESET; config.windows.len()],
            centroider: Centroider::new(config.centroid),
            values: vec![0; largest],
            sorted: vec![0; largest],
            results: Vec::with_capacity(config.windows.len()),
            calibration,
        }
    }

    /// Window `k`: the kept set's threshold (`p >= kept_from` is kept) and
    /// the instantaneous level, from the sorted values (SPEC.md §3).
    fn select(&self, sorted: &[i32], n: usize) -> (i32, Option<i32>) {
        let count = sorted.len();
        // v(k) = sorted[count - k].
        let v = |k: usize| sorted[count - k];
        // Index of the largest value strictly below v(N), if any.
        let below = || sorted[..count - n].iter().rposition(|&p| p < v(n));
        match self.rule {
            SelectionRule::Threshold => (v(n), None),
            SelectionRule::SubtractNext => (v(n + 1).saturating_add(1), Some(v(n + 1))),
            SelectionRule::SubtractNextDistinct => (v(n), below().map(|i| sorted[i])),
            SelectionRule::SubtractMean { count: m } => {
                let level = below().map(|last| {
                    let first = (last + 1).saturating_sub(m as usize);
                    let taken = &sorted[first..=last];
                    let sum: i64 = taken.iter().map(|&p| p as i64).sum();
                    sum.div_euclid(taken.len() as i64) as i32
                });
                (v(n), level)
            }
        }
    }
}

impl Peer for SortPeer<'_> {
    fn name(&self) -> &'static str {
        "per-window sort (engine arithmetic)"
    }

    fn process(&mut self, frame: &[u16], out: &mut [PeerSlope]) {
        self.results.clear();
        let count = self.calibration.windows.len();
        for (k, slot) in out.iter_mut().enumerate().take(count) {
            let w = self.calibration.windows[k];
            let count = w.pixel_count();
            let mut values = std::mem::take(&mut self.values);
            let mut sorted = std::mem::take(&mut self.sorted);
            let values_k = &mut values[..count];
            self.calibration.window(frame, k, values_k, |p| p);
            let n = self.calibration.counts[k] as usize;
            let mut moments = Moments::ZERO;
            let width = w.width as usize;
            if n >= count {
                for (q, &p) in values_k.iter().enumerate() {
                    moments.add(p, (q % width) as u16, (q / width) as u16);
                }
            } else {
                let sorted_k = &mut sorted[..count];
                sorted_k.copy_from_slice(values_k);
                sorted_k.sort_unstable();
                let (kept_from, level) = self.select(sorted_k, n);
                let level = match self.gain_shift {
                    Some(g) => self.filters[k].update(level, g),
                    None => level,
                };
                for (q, &p) in values_k.iter().enumerate() {
                    let weight = match (p >= kept_from, level) {
                        (false, _) => 0,
                        (true, Some(l)) => (p - l).max(0),
                        (true, None) => p,
                    };
                    moments.add(weight, (q % width) as u16, (q / width) as u16);
                }
            }
            let result = self.centroider.result(k as u16, moments, w.width, w.height);
            *slot = PeerSlope {
                x: result.slope_x as f64 / 65536.0,
                y: result.slope_y as f64 / 65536.0,
                valid: result.valid,
            };
            self.results.push(result);
            self.values = values;
            self.sorted = sorted;
        }
    }
}

/// How a [`FloatPeer`] finds `v(N)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Selector {
    /// A full sort (DARC as flown).
    Sort,
    /// `select_nth_unstable_by` (C++ `nth_element`).
    NthElement,
    /// [`select_branch_free`].
    BranchFree,
}

/// DARC's method (subtract-next-distinct) in `f32`, with one of three ways
/// to find `v(N)`.
pub struct FloatPeer {
    calibration: Calibration,
    selector: Selector,
    min_flux: f32,
    reference: Option<Vec<[i32; 2]>>,
    values: Vec<f32>,
    scratch: Vec<f32>,
}

impl FloatPeer {
    pub fn new(config: &Config<'_>, selector: Selector) -> Self {
        let calibration = Calibration::new(config);
        let largest = calibration.largest_window();
        FloatPeer {
            selector,
            min_flux: config.centroid.min_flux as f32,
            reference: config.centroid.reference_slopes.map(<[[i32; 2]]>::to_vec),
            values: vec![0.0; largest],
            scratch: vec![0.0; largest],
            calibration,
        }
    }

    /// `v(N)` and the largest value below it (0 if none: nothing is
    /// subtracted), from a scratch copy of `values`.
    #[inline]
    fn levels(&self, values: &[f32], scratch: &mut [f32], n: usize) -> (f32, f32) {
        let count = values.len();
        scratch.copy_from_slice(values);
        let k = count - n;
        match self.selector {
            Selector::Sort => {
                scratch.sort_unstable_by(f32::total_cmp);
                let top = scratch[k];
                let mut i = k;
                while i > 0 && scratch[i - 1] == top {
                    i -= 1;
                }
                (top, if i > 0 { scratch[i - 1] } else { 0.0 })
            }
            Selector::NthElement => {
                let (lower, &mut top, _) = scratch.select_nth_unstable_by(k, f32::total_cmp);
                let below = lower
                    .iter()
                    .filter(|&&p| p < top)
                    .fold(f32::NEG_INFINITY, |m, &p| m.max(p));
                (
                    top,
                    if below == f32::NEG_INFINITY {
                        0.0
                    } else {
                        below
                    },
                )
            }
            Selector::BranchFree => {
                let top = select_branch_free(scratch, k);
                let mut below = f32::NEG_INFINITY;
                for &p in &scratch[..k] {
                    below = below.max(if p < top { p } else { f32::NEG_INFINITY });
                }
                (
                    top,
                    if below == f32::NEG_INFINITY {
                        0.0
                    } else {
                        below
                    },
                )
            }
        }
    }
}

impl Peer for FloatPeer {
    fn name(&self) -> &'static str {
        match self.selector {
            Selector::Sort => "DARC (f32 copy, quicksort, next-distinct)",
            Selector::NthElement => "nth_element quickselect (f32, next-distinct)",
            Selector::BranchFree => "branch-free quickselect (f32, next-distinct)",
        }
    }

    fn process(&mut self, frame: &[u16], out: &mut [PeerSlope]) {
        let mut values = std::mem::take(&mut self.values);
        let mut scratch = std::mem::take(&mut self.scratch);
        for k in 0..self.calibration.windows.len() {
            let w = self.calibration.windows[k];
            let count = w.pixel_count();
            let values = &mut values[..count];
            self.calibration.window(frame, k, values, |p| p as f32);
            let n = self.calibration.counts[k] as usize;
            let (top, below) = if n >= count {
                (f32::NEG_INFINITY, 0.0)
            } else {
                self.levels(values, &mut scratch[..count], n)
            };
            let (mut f, mut fx, mut fy) = (0f32, 0f32, 0f32);
            for (j, row) in values.chunks_exact(w.width as usize).enumerate() {
                let mut row_sum = 0f32;
                for (i, &p) in row.iter().enumerate() {
                    let weight = if p >= top { p - below } else { 0.0 };
                    row_sum += weight;
                    fx += weight * i as f32;
                }
                f += row_sum;
                fy += row_sum * j as f32;
            }
            out[k] = if f > self.min_flux {
                let reference = self.reference.as_ref().map_or([0, 0], |r| r[k]);
                PeerSlope {
                    x: (fx / f - (w.width as f32 - 1.0) / 2.0) as f64
                        - reference[0] as f64 / 65536.0,
                    y: (fy / f - (w.height as f32 - 1.0) / 2.0) as f64
                        - reference[1] as f64 / 65536.0,
                    valid: true,
                }
            } else {
                PeerSlope::default()
            };
        }
        self.values = values;
        self.scratch = scratch;
    }
}

/// The `k`-th smallest of `values` (0-based), leaving `values[..k]` no
/// greater and `values[k + 1..]` no smaller. Quickselect with a
/// median-of-three pivot whose partition loops have no data-dependent
/// branch: each element is swapped to the boundary unconditionally and the
/// boundary advances by the comparison's 0 or 1 (a partition that found
/// nothing below the pivot is redone on `<=`, so ties cannot stall it).
pub fn select_branch_free(values: &mut [f32], k: usize) -> f32 {
    assert!(k < values.len(), "k = {k} of {} values", values.len());
    let (mut lo, mut hi) = (0, values.len());
    while hi - lo > 8 {
        let mid = lo + (hi - lo) / 2;
        let (a, b, c) = (values[lo], values[mid], values[hi - 1]);
        let pivot = a.max(b).min(a.min(b).max(c));
        let split = partition(&mut values[lo..hi], |v| v < pivot) + lo;
        if k < split {
            hi = split;
            continue;
        }
        // Split off the values equal to the pivot (there is at least one).
        let equal_end = partition(&mut values[split..hi], |v| v <= pivot) + split;
        if k < equal_end {
            return pivot;
        }
        lo = equal_end;
    }
    // Insertion sort of the last few.
    for i in lo + 1..hi {
        let mut j = i;
        while j > lo && values[j - 1] > values[j] {
            values.swap(j - 1, j);
            j -= 1;
        }
    }
    values[k]
}

/// Moves the values for which `below` holds to the front; returns how many.
#[inline(always)]
fn partition(values: &mut [f32], below: impl Fn(f32) -> bool) -> usize {
    let mut boundary = 0;
    for i in 0..values.len() {
        values.swap(i, boundary);
        boundary += below(values[boundary]) as usize;
    }
    boundary
}

/// The peers of the bench, on `config`'s windows and calibration: the sort
/// in the engine's arithmetic (the configuration's rule) and DARC's method
/// three ways.
pub fn all_peers<'c>(config: &Config<'c>) -> Vec<Box<dyn Peer + 'c>> {
    vec![
        Box::new(SortPeer::new(config)),
        Box::new(FloatPeer::new(config, Selector::Sort)),
        Box::new(FloatPeer::new(config, Selector::NthElement)),
        Box::new(FloatPeer::new(config, Selector::BranchFree)),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn branch_free_select_finds_the_kth_with_ties() {
        let mut state = 7u64;
        for len in 1..70usize {
            for spread in [1u64, 3, 1000] {
                let values: Vec<f32> = (0..len)
                    .map(|_| {
                        state ^= state << 13;
                        state ^= state >> 7;
                        state ^= state << 17;
                        (state % spread) as f32
                    })
                    .collect();
                let mut sorted = values.clone();
                sorted.sort_by(f32::total_cmp);
                for k in 0..len {
                    let mut v = values.clone();
                    let got = select_branch_free(&mut v, k);
                    assert_eq!(got, sorted[k], "len {len} spread {spread} k {k}");
                    assert!(v[..k].iter().all(|&p| p <= got));
                    assert!(v[k + 1..].iter().all(|&p| p >= got));
                }
            }
        }
    }
}
