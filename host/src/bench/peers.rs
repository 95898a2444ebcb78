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
    /// Window-local column and row of each pixel of the last window shape
    /// (for the lane-parallel centre of gravity).
    coordinates: ((u16, u16), Vec<f32>, Vec<f32>),
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
            scratch: vec![0.0; 2 * largest],
            coordinates: ((0, 0), Vec::new(), Vec::new()),
            calibration,
        }
    }

    /// Column and row of each pixel of a `width` x `height` window.
    fn coordinates(&mut self, width: u16, height: u16) -> (&[f32], &[f32]) {
        if self.coordinates.0 != (width, height) {
            let count = width as usize * height as usize;
            let w = width as usize;
            self.coordinates = (
                (width, height),
                (0..count).map(|q| (q % w) as f32).collect(),
                (0..count).map(|q| (q / w) as f32).collect(),
            );
        }
        (&self.coordinates.1, &self.coordinates.2)
    }

    /// `v(N)` and the largest value below it (0 if none: nothing is
    /// subtracted), using `scratch` (twice `values` long).
    #[inline]
    fn levels(&self, values: &[f32], scratch: &mut [f32], n: usize) -> (f32, f32) {
        let count = values.len();
        let k = count - n;
        match self.selector {
            Selector::Sort => {
                let scratch = &mut scratch[..count];
                scratch.copy_from_slice(values);
                scratch.sort_unstable_by(f32::total_cmp);
                let top = scratch[k];
                let mut i = k;
                while i > 0 && scratch[i - 1] == top {
                    i -= 1;
                }
                (top, if i > 0 { scratch[i - 1] } else { 0.0 })
            }
            Selector::NthElement => {
                let scratch = &mut scratch[..count];
                scratch.copy_from_slice(values);
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
                let top = select_branch_free(values, k, scratch);
                let below = largest_below(values, top);
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
            Selector::BranchFree => "branch-free quickselect, 8-lane sums (f32, next-distinct)",
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
                self.levels(values, &mut scratch[..2 * count], n)
            };
            let (f, fx, fy) = if self.selector == Selector::BranchFree {
                let (columns, rows) = self.coordinates(w.width, w.height);
                moments_lanes(values, top, below, columns, rows)
            } else {
                // DARC's loops: one running sum each.
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
                (f, fx, fy)
            };
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

/// The `k`-th smallest of `values` (0-based), using `work` (at least twice
/// `values.len()`) and leaving `values` as it was. A quickselect whose
/// partition loops have no data-dependent branch: each value is written to
/// both ends of the other half of `work` and one end advances by the
/// comparison's 0 or 1 (two stores, no load of what was just stored). The
/// pivot is a sample value near `k`'s quantile (nine spread over the
/// values, sorted by a min/max network), so that the side kept is usually
/// small; a partition that finds nothing below the pivot is redone on `<=`
/// to split off the values equal to it, so ties cannot stall it.
pub fn select_branch_free(values: &[f32], k: usize, work: &mut [f32]) -> f32 {
    let len = values.len();
    assert!(k < len, "k = {k} of {len} values");
    assert!(
        work.len() >= 2 * len,
        "work of {} for {len} values",
        work.len()
    );
    let (mut src, mut dst) = work.split_at_mut(len);
    src.copy_from_slice(values);
    let (mut from, mut to) = (0, len);
    let mut k = k;
    loop {
        let m = to - from;
        let part = &src[from..to];
        if m <= 12 {
            let mut small = [0f32; 12];
            small[..m].copy_from_slice(part);
            sort_network(&mut small[..m]);
            return small[k];
        }
        let pivot = sampled_pivot(part, k);
        let out = &mut dst[from..to];
        let below = split(part, out, |v| v < pivot);
        let (keep_from, keep_to) = if k < below {
            (0, below)
        } else if below > 0 {
            k -= below;
            (below, m)
        } else {
            // Nothing below the pivot: split off the values equal to it.
            let equal = split(part, out, |v| v <= pivot);
            if k < equal {
                return pivot;
            }
            k -= equal;
            (equal, m)
        };
        std::mem::swap(&mut src, &mut dst);
        (from, to) = (from + keep_from, from + keep_to);
    }
}

/// Writes the values of `part` for which `below` holds to the front of
/// `out` and the others to its back; returns how many are in front.
#[inline(always)]
fn split(part: &[f32], out: &mut [f32], below: impl Fn(f32) -> bool) -> usize {
    assert_eq!(part.len(), out.len());
    let (mut front, mut back) = (0, out.len());
    for &v in part {
        // SAFETY: before the t-th value, front + (len - back) = t < len, so
        // front < back <= len: both indices are in bounds. (Bounds checks
        // would double the loop: this is the peer at its best.)
        unsafe {
            *out.get_unchecked_mut(front) = v;
            *out.get_unchecked_mut(back - 1) = v;
        }
        let b = below(v) as usize;
        front += b;
        back -= 1 - b;
    }
    front
}

/// Lanes of the lane-parallel sums: independent running sums that the
/// compiler keeps in vector registers.
const LANES: usize = 8;

/// The largest of `values` below `top` (minus infinity if none).
#[inline]
fn largest_below(values: &[f32], top: f32) -> f32 {
    let mut lanes = [f32::NEG_INFINITY; LANES];
    let chunks = values.chunks_exact(LANES);
    let tail = chunks.remainder();
    for chunk in chunks {
        for (m, &p) in lanes.iter_mut().zip(chunk) {
            *m = m.max(if p < top { p } else { f32::NEG_INFINITY });
        }
    }
    let mut largest = lanes.iter().fold(f32::NEG_INFINITY, |a, &b| a.max(b));
    for &p in tail {
        largest = largest.max(if p < top { p } else { f32::NEG_INFINITY });
    }
    largest
}

/// Sum of weights and of weights times column and row, in [`LANES`]
/// independent sums, with weight `p - below` for `p >= top`, else 0.
#[inline]
fn moments_lanes(
    values: &[f32],
    top: f32,
    below: f32,
    columns: &[f32],
    rows: &[f32],
) -> (f32, f32, f32) {
    let (mut f, mut fx, mut fy) = ([0f32; LANES], [0f32; LANES], [0f32; LANES]);
    let count = values.len() / LANES * LANES;
    for ((v, i), j) in values[..count]
        .chunks_exact(LANES)
        .zip(columns[..count].chunks_exact(LANES))
        .zip(rows[..count].chunks_exact(LANES))
    {
        for l in 0..LANES {
            let weight = if v[l] >= top { v[l] - below } else { 0.0 };
            f[l] += weight;
            fx[l] += weight * i[l];
            fy[l] += weight * j[l];
        }
    }
    let (mut f, mut fx, mut fy) = (f.iter().sum(), fx.iter().sum(), fy.iter().sum::<f32>());
    for q in count..values.len() {
        let weight = if values[q] >= top {
            values[q] - below
        } else {
            0.0
        };
        f += weight;
        fx += weight * columns[q];
        fy += weight * rows[q];
    }
    (f, fx, fy)
}

/// A pivot from nine samples spread over `part`: the sample just below
/// `k`'s quantile if `k` is in the upper half (the part above the pivot,
/// where `k` then is, is small), just above it otherwise.
#[inline(always)]
fn sampled_pivot(part: &[f32], k: usize) -> f32 {
    let m = part.len();
    let mut sample = [0f32; 9];
    for (i, s) in sample.iter_mut().enumerate() {
        *s = part[(2 * i + 1) * m / 18];
    }
    sort_network(&mut sample);
    let rank = (k * 9 / m).min(8);
    sample[if 2 * k >= m {
        rank.saturating_sub(1)
    } else {
        (rank + 1).min(8)
    }]
}

/// Sorts a few values with compare-exchanges (min/max: no branches).
#[inline(always)]
fn sort_network(values: &mut [f32]) {
    for i in 1..values.len() {
        for j in (1..=i).rev() {
            let (a, b) = (values[j - 1], values[j]);
            values[j - 1] = a.min(b);
            values[j] = a.max(b);
        }
    }
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
                let mut work = vec![0f32; 2 * len];
                for (k, &want) in sorted.iter().enumerate() {
                    let got = select_branch_free(&values, k, &mut work);
                    assert_eq!(got, want, "len {len} spread {spread} k {k}");
                }
            }
        }
    }
}
