//! `subtract-next` windows that keep most of their pixels (N above half
//! of them, no level filter) select the *complement*: `v(N+1)` is then the
//! `K`-th smallest of the window's `P` values, `K = P - N`, and
//!
//! `sum_{p > v} (p - v) i = (sum_all p i - v sum_all i) - sum_{p < v} (p - v) i`
//!
//! (likewise `j` and the plain sum; pixels equal to `v` weigh nothing
//! either way). So a segment adds every pixel's calibrated value to the
//! window's sums and keeps as candidates only the pixels at or below a
//! *ceiling* set from the seed (its hint plus its margin): the hot loop is
//! `scan::complement`'s, a window at a time on the general path, or a
//! whole row when every open window selects the complement; at
//! the end ([`Engine::finish_complement`]) `v(N+1)` is the `K`-th
//! smallest candidate if there are at least `K` of them (every other
//! pixel is above the ceiling, hence above it), and the pixels below it
//! are all candidates. Fewer than `K`: the ordinary end's rescan (such a
//! window is marked for one from its opening, so that no other end takes
//! it: see [`Engine::update_complement`]).
//!
//! Exact integer identities, as in `closed_form`: the result is the
//! ordinary end's bit for bit. At N = 200 of 256 the bench's windows keep
//! ~117 candidates each (their cutoff lies in the background's level)
//! where the ordinary path admitted ~220.

use super::{Engine, OutputSink};
use crate::engine::calibrate::{self, Steps};
use crate::engine::centroid::Moments;
use crate::engine::scan::{self, RowStop};
use crate::engine::select::{self, Entry};
use crate::engine::window::OpenWindow;
use brightpix_protocol::{Config, SelectionRule};

use super::closed_form::weigh;

/// `OpenWindow::attention` of a window selecting the complement: an
/// address the front never reaches, distinct from `last_row::PREPARED`.
pub(super) const COMPLEMENT: usize = usize::MAX - 2;

/// Up to this deep on either side of the previous cutoff, `v(N+1)` is
/// found by one pass keeping the few nearest (`select::extreme`); deeper,
/// by a selection on a copy.
const MOST_DEEP: usize = 8;

/// Whether a window with N `n` of `pixels` pixels selects the complement
/// (given a configuration for which [`applies`] holds).
#[inline(always)]
pub(super) fn selects(n: u16, pixels: usize) -> bool {
    2 * n as usize > pixels && (n as usize) < pixels
}

/// Whether some window of `config` selects the complement: `subtract-next`
/// without a level filter (whose weights `p - v(N+1)` make pixels equal to
/// `v(N+1)` weigh nothing, so the tie among them does not matter).
pub(super) fn applies(config: &Config<'_>) -> bool {
    config.selection.rule == SelectionRule::SubtractNext
        && config.selection.level_filter.is_none()
        && (0..config.windows.len())
            .any(|k| selects(config.pixel_count(k), config.windows[k].pixel_count()))
}

/// The seed's hint (the previous `v(N+1)`) plus its margin; every value
/// before the first frame.
#[inline(always)]
fn ceiling(hint: i32, low: i32) -> i32 {
    if hint == i32::MIN {
        i32::MAX
    } else {
        hint.saturating_add(hint - low)
    }
}

impl Engine<'_, '_> {
    /// After the open windows changed (`update_layout`): makes those just
    /// opened (in the current row) that select the complement, with room
    /// for all their pixels, do so, and sets `all_complement`. Such a
    /// window gets floor 0 and an empty kernel segment (the row kernel
    /// skips it; the general path, `segment_rest`, hands its segments to
    /// `scan::complement`), the ceiling in `hint` and the previous cutoff
    /// in `low` (from the seed's thresholds, which it held), the sums in
    /// `moments` (zero), the candidates in the front tier (empty). Out of
    /// line, so that configurations without such windows pay one test a
    /// layout change. It is also marked for a rescan: its candidates are not
    /// the tiers the other ends read, so none of them takes it
    /// (`finish_ordinary` tries its own end first, and rescans if that
    /// falls short).
    #[inline(never)]
    pub(super) fn update_complement(&mut self) {
        for window in self.memory.open[..self.open_len].iter_mut() {
            let pixels = window.pixels() as usize;
            if window.y != self.row
                || window.attention == COMPLEMENT
                || window.capacity == 0
                || !selects(window.n, pixels)
                || (window.capacity as usize) < pixels
            {
                continue;
            }
            let (hint, low) = (window.hint, window.low);
            window.attention = COMPLEMENT;
            window.floor = 0;
            window.hint = ceiling(hint, low);
            window.low = hint;
            window.rescan = true;
            if window.segment_start != window.segment_end {
                window.segment_end = window.segment_start;
                self.not_ready += 1;
            }
        }
        let open = &self.memory.open[..self.open_len];
        self.all_complement = !open.is_empty()
            && open
                .iter()
                .all(|w| w.attention == COMPLEMENT && (w.x | w.width) & 1 == 0);
    }

    /// The end of complement window `k` (see the module documentation):
    /// `false` (nothing done) if fewer than `K` candidates came; the
    /// ordinary end then rescans it. Out of line, so that
    /// `finish_ordinary`, which the other windows take, stays as they need
    /// it.
    #[inline(never)]
    pub(super) fn finish_complement(&mut self, k: usize, sink: &mut impl OutputSink) -> bool {
        let window = &mut self.memory.open[k];
        let (width, height) = (window.width as i64, window.height as i64);
        let pixels = window.pixels() as usize;
        let below = pixels - window.n as usize;
        let m = window.front();
        if m < below {
            return false;
        }
        // SAFETY: the window's buffer (opened with it), no other reference
        // to it alive.
        let candidates: &[Entry] = unsafe { &window.entries()[..m] };
        // `v(N+1)` is the `below`-th smallest candidate. One pass counts
        // those below the previous cutoff (kept in `low`) and its copies,
        // and weighs the former at it: most often (the cutoff in a level
        // held by many pixels, such as the background's) `v(N+1)` is the
        // previous cutoff again and that pass is the end.
        let previous = window.low;
        let (mut less, mut equal) = (0usize, 0usize);
        // Of `d = p - previous` (below 2^23 in size): its sum, and its
        // sums times the packed position `(j << 6) + i` and times `j`.
        let (mut sum_d, mut sum_d_position, mut sum_dj) = (0i64, 0i64, 0i64);
        for e in candidates {
            if e.value < previous {
                less += 1;
                let d = e.value - previous;
                sum_d += d as i64;
                sum_d_position += d as i64 * (e.position & 0xfff) as i32 as i64;
                sum_dj += d as i64 * (e.position >> 6 & 63) as i32 as i64;
            } else {
                equal += (e.value == previous) as usize;
            }
        }
        let sums = window.moments;
        if less < below && below <= less + equal {
            let under = Moments {
                sum_w: sum_d,
                sum_wi: sum_d_position - 64 * sum_dj,
                sum_wj: sum_dj,
            };
            let all = all_pixels(&sums, previous, width, height);
            self.emit(k, previous, minus(all, under), sink);
            return true;
        }
        // Among the few largest below the previous cutoff, or the few
        // smallest above it; deeper, by a selection on a copy.
        let v = if below <= less && less - below < MOST_DEEP {
            let values = candidates.iter().map(|e| e.value).filter(|&p| p < previous);
            select::extreme::<true>(values, less - below + 1)
        } else if below > less + equal && below - less - equal <= MOST_DEEP {
            let values = candidates.iter().map(|e| e.value).filter(|&p| p > previous);
            select::extreme::<false>(values, below - less - equal)
        } else {
            let copy = &mut self.memory.scratch[..m];
            for (c, e) in copy.iter_mut().zip(candidates) {
                *c = e.value;
            }
            *copy.select_nth_unstable(below - 1).1
        };
        // Every pixel below `v` is a candidate: out of the sums of all.
        let mut moments = all_pixels(&sums, v, width, height);
        for e in candidates.iter().filter(|e| e.value < v) {
            weigh(&mut moments, e, v as i64, -1);
        }
        self.emit(k, v, moments, sink);
        true
    }
}

/// `a - b`, field by field.
#[inline(always)]
fn minus(a: Moments, b: Moments) -> Moments {
    Moments {
        sum_w: a.sum_w - b.sum_w,
        sum_wi: a.sum_wi - b.sum_wi,
        sum_wj: a.sum_wj - b.sum_wj,
    }
}

/// The moments of `p - v` over every pixel of a `width` x `height` window
/// whose calibrated values' sums are `sums` (`sum_wi` doubled, see
/// `scan::complement`).
#[inline(always)]
fn all_pixels(sums: &Moments, v: i32, width: i64, height: i64) -> Moments {
    let v = v as i64;
    Moments {
        sum_w: sums.sum_w - v * width * height,
        sum_wi: sums.sum_wi / 2 - v * height * (width * (width - 1) / 2),
        sum_wj: sums.sum_wj - v * width * (height * (height - 1) / 2),
    }
}

impl Engine<'_, '_> {
    /// [`push_whole_row`](Self::push_whole_row) when every open window
    /// selects the complement (`all_complement`), for a word-aligned row
    /// (gapless below 16 bits): one pass of `scan::complement::row`. Out
    /// of line, so that the other configurations' row path stays as it
    /// was (inlined, it changed that path's register allocation: +0.1
    /// instructions a pixel on every other workload).
    #[inline(never)]
    pub(super) fn complement_row<S: Steps, const CHECK: bool>(
        &mut self,
        row_address: usize,
        sink: &mut impl OutputSink,
    ) -> Result<(), usize> {
        self.scan_row(row_address);
        // SAFETY: every open window selects the complement, with room for
        // all its pixels and whole words for segments; the row holds them
        // and the maps cover it.
        let stop = unsafe { scan::complement::row::<S, CHECK>(&mut self.scan) };
        if let RowStop::OutOfRange { window, pixel } = stop {
            let k = (window - self.scan.first) / core::mem::size_of::<OpenWindow>();
            self.finish_before(k, sink);
            return Err((pixel - row_address) / 2);
        }
        if self.row == self.next_last_row {
            self.finish_last_row(sink);
        }
        Ok(())
    }

    /// Complement window `k`'s pixels of the current row on the general
    /// path (`segment_rest`'s arguments). Out of line, so that
    /// `segment_rest` stays as the other windows need it.
    #[inline(never)]
    pub(super) fn complement_segment<S: Steps, const CHECK: bool>(
        &mut self,
        k: usize,
        raw: &[u16],
        pixel: usize,
        i0: u16,
        j: u16,
    ) -> Result<(), usize> {
        // SAFETY: the segment lies in the camera (a window's row, validated
        // configuration).
        let maps = unsafe { calibrate::run_maps::<S>(&self.config.calibration, pixel, raw.len()) };
        let window = &mut self.memory.open[k];
        scan::complement::segment::<S, CHECK>(window, raw, maps, i0, j, self.max_raw)
    }
}
