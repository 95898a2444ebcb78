//! A window's end: the cutoff among its candidates (or, when the seed was
//! too high, among all its pixels again from the row history or the whole
//! frame the caller holds), the level
//! filter and seed updated, the moments and the sub-aperture's result.

use super::admission::settle_at_hint;
use super::closed_form::{filtered_below, level_from_below, MOST_FRONT};
use super::complement::COMPLEMENT;
use super::last_row::PREPARED;
use super::{Engine, OutputSink};
use crate::engine::calibrate::Calibrator;
use crate::engine::centroid::{self, Moments};
use crate::engine::select::{self, pack, Cut, Entry, Tiers, WindowRule};
use crate::engine::window::{OpenWindow, SubapertureState};
use brightpix_protocol::{Config, SelectionRule};

impl Engine<'_, '_> {
    /// A window's last pixel has arrived: its result, and what it leaves for
    /// the next frame (level filter, seed).
    #[inline(always)]
    pub(super) fn finish(&mut self, k: usize, sink: &mut impl OutputSink) {
        let window = &self.memory.open[k];
        if window.attention == PREPARED {
            self.finish_prepared(k, sink);
            return;
        }
        let selects = window.capacity != 0;
        if self.closed_form && selects && self.finish_in_closed_form::<false>(k, sink) {
            return;
        }
        if self.level_closed_form
            && selects
            && self.finish_level_rule_in_closed_form::<false>(k, sink)
        {
            return;
        }
        if self.filtered_closed_form && selects && self.finish_filtered_in_closed_form(k, sink) {
            return;
        }
        self.finish_ordinary(k, sink);
    }

    /// The ordinary end: the cutoff by a selection over the tiers (or a
    /// rescan), the moments by a pass over the candidates kept. A window
    /// selecting the complement (marked for a rescan, so that no other end
    /// takes it) ends its own way here first, if it can.
    #[inline(never)]
    pub(super) fn finish_ordinary(&mut self, k: usize, sink: &mut impl OutputSink) {
        let window = &self.memory.open[k];
        // Tested in this order, so that the other windows (rarely marked
        // for a rescan) pay one test.
        if window.rescan && window.attention == COMPLEMENT && self.finish_complement(k, sink) {
            return;
        }
        self.finished_in_row = true;
        let memory = &mut self.memory;
        let window = &mut memory.open[k];
        window.finished = true;
        let moments = if window.capacity == 0 {
            window.moments
        } else {
            let rule = WindowRule {
                rule: self.config.selection.rule,
                n: window.n,
                pixels: window.pixels(),
            };
            let state = &mut memory.subapertures[window.index as usize];
            let capacity = window.capacity as usize;
            settle_at_hint(window);
            let (front, back) = (window.front(), window.back());
            // SAFETY: the window's buffer (opened with it), no other
            // reference to it alive.
            let entries: &[Entry] = unsafe { window.entries() };
            let filter = self.config.selection.level_filter;
            let level = |cut: &Cut, state: &mut SubapertureState| match filter {
                Some(f) => state.level.update(cut.level, f.gain_shift),
                None => cut.level,
            };
            let held =
                front + back + window.hint_ties.count as usize + window.low_ties.count as usize;
            self.stats.windows = self.stats.windows.wrapping_add(1);
            self.stats.candidates = self.stats.candidates.wrapping_add(held as u32);
            let mut too_high = false;
            let from_buffer = if window.rescan {
                None
            } else {
                let mut tiers = Tiers {
                    front: &entries[..front],
                    front_at_hint: window.at_hint,
                    hint: window.hint,
                    hint_ties: window.hint_ties.count,
                    back: &entries[capacity - back..],
                    low: window.low,
                    low_ties: window.low_ties.count,
                    complete: held == rule.pixels as usize,
                    scratch: memory.scratch,
                };
                let cut = select::cut(&rule, &mut tiers).ok();
                too_high = cut.is_none();
                cut
            };
            match from_buffer {
                Some(cut) => {
                    let level = level(&cut, state);
                    state.seed.observe(cut.cutoff, false);
                    let mut moments = Moments::ZERO;
                    select::add_moments(&mut moments, &cut, level, &entries[..front]);
                    select::add_tie_moments(
                        &mut moments,
                        &cut,
                        level,
                        window.hint,
                        window.hint_ties,
                    );
                    if cut.bound < window.hint {
                        let at = capacity - back;
                        select::add_moments(&mut moments, &cut, level, &entries[at..]);
                        select::add_tie_moments(
                            &mut moments,
                            &cut,
                            level,
                            window.low,
                            window.low_ties,
                        );
                    }
                    moments
                }
                None => 'rescan: {
                    self.stats.rescans = self.stats.rescans.wrapping_add(1);
                    let pixels = rule.pixels as usize;
                    let rows = WindowRows::new(
                        memory.history,
                        self.history_rows,
                        self.whole_frame,
                        &self.config,
                    );
                    // A bound below `low` (the cutoff is below it, usually
                    // by less than the margin again: `rescan_bound`).
                    let bound = rescan_bound(window.low, window.hint);
                    // A window whose seed was too high holds every pixel at
                    // or above `low` as entries (unless a raise made it
                    // strict, or ties were counted): only the pixels in
                    // `[bound, low)` are read again, after a copy of its
                    // back tier, and cut with its tiers, the copy and them
                    // the back (as `Engine::take_missed_rows` before the
                    // last row).
                    let held_whole = !window.rescan
                        && !window.strict
                        && window.hint_ties.count == 0
                        && window.low_ties.count == 0;
                    if held_whole
                        && matches!(
                            rule.rule,
                            SelectionRule::SubtractNextDistinct
                                | SelectionRule::SubtractMean { .. }
                        )
                    {
                        let filter = filter.map(|f| f.gain_shift);
                        let end = (entries, &rule, bound, filter);
                        let scratch = &mut *memory.scratch;
                        let calibrator = &self.calibrator;
                        if let Some(moments) =
                            level_below_low(&rows, window, calibrator, end, scratch, state)
                        {
                            break 'rescan moments;
                        }
                    }
                    if held_whole {
                        let lower = cut_below_low(
                            &rows,
                            window,
                            &self.calibrator,
                            (entries, &rule, bound),
                            memory.rescan,
                            memory.scratch,
                        );
                        if let Some((cut, lower)) = lower {
                            let level = level(&cut, state);
                            state.seed.observe(cut.cutoff, too_high);
                            // No ties: the front's pixels and the new back's.
                            let mut moments = Moments::ZERO;
                            select::add_moments(&mut moments, &cut, level, &entries[..front]);
                            select::add_moments(&mut moments, &cut, level, &memory.rescan[..lower]);
                            break 'rescan moments;
                        }
                    }
                    // Else the pixels at or above `bound`, cut as the
                    // candidates of a window raised to it, which holds if it
                    // is `Ok`; else every pixel, calibrated again. A window
                    // held whole was just cut at `bound` with those very
                    // pixels (and fell short): straight to every pixel.
                    let cut_at_bound = if held_whole {
                        None
                    } else {
                        let (kept, at_bound) =
                            rows.candidates(window, &self.calibrator, bound, memory.rescan);
                        let mut tiers = Tiers {
                            front: &memory.rescan[..kept],
                            front_at_hint: at_bound,
                            hint: bound,
                            hint_ties: 0,
                            back: &[],
                            low: bound,
                            low_ties: 0,
                            complete: kept == pixels,
                            scratch: memory.scratch,
                        };
                        select::cut(&rule, &mut tiers).ok().map(|cut| (cut, kept))
                    };
                    let (cut, kept) = match cut_at_bound {
                        Some(cut) => cut,
                        None => {
                            rows.candidates(window, &self.calibrator, i32::MIN, memory.rescan);
                            let mut tiers = Tiers {
                                front: &memory.rescan[..pixels],
                                front_at_hint: 0,
                                hint: i32::MIN,
                                hint_ties: 0,
                                back: &[],
                                low: i32::MIN,
                                low_ties: 0,
                                complete: true,
                                scratch: memory.scratch,
                            };
                            // Complete candidates always cut (N < pixels);
                            // the fallback keeps nothing and is never taken.
                            let cut = select::cut(&rule, &mut tiers).unwrap_or(KEEPS_NOTHING);
                            (cut, pixels)
                        }
                    };
                    let level = level(&cut, state);
                    state.seed.observe(cut.cutoff, too_high);
                    let mut moments = Moments::ZERO;
                    select::add_moments(&mut moments, &cut, level, &memory.rescan[..kept]);
                    moments
                }
            }
        };
        sink.subaperture(self.centroider.result(
            window.index,
            moments,
            window.width,
            window.height,
        ));
    }
}

/// The cut of a window that holds every pixel at or above `low` as entries
/// (none of them in tie buckets) once the pixels in `[bound, low)` are read
/// again: they and a copy of the back tier, the new back, in `rescan` (its
/// length returned with the cut); `None` if the cut still falls short. Out
/// of line, so that the usual end does not carry it.
#[cold]
#[inline(never)]
fn cut_below_low(
    rows: &WindowRows<'_>,
    window: &OpenWindow,
    calibrator: &Calibrator<'_>,
    (entries, rule, bound): (&[Entry], &WindowRule, i32),
    rescan: &mut [Entry],
    scratch: &mut [i32],
) -> Option<(Cut, usize)> {
    let (front, back, capacity) = (window.front(), window.back(), window.capacity as usize);
    rescan[..back].copy_from_slice(&entries[capacity - back..]);
    let range = (bound, window.low);
    let rows_all = window.height as usize;
    let added = rows.between(window, calibrator, range, rows_all, &mut rescan[back..])?;
    let mut tiers = Tiers {
        front: &entries[..front],
        front_at_hint: window.at_hint,
        hint: window.hint,
        hint_ties: 0,
        back: &rescan[..back + added],
        low: bound,
        low_ties: 0,
        complete: front + back + added == rule.pixels as usize,
        scratch,
    };
    let cut = select::cut(rule, &mut tiers).ok()?;
    Some((cut, back + added))
}

/// The end of a `subtract-next-distinct` or `subtract-mean` window held
/// whole (every pixel at or above `low` an entry, no ties) whose cut fell
/// short with N or more entries: no entry lies below `v(N)` (it would have
/// set the level), so `v(N)` is the smallest entry, every entry is kept,
/// and the level comes from the pixels below `low` alone. Those in
/// `[bound, low)` are read again, values only, into `scratch`; if they set
/// the level (`level_from_below`), the moments are the entries' sums at it
/// in closed form, without the selection and the pass over what a cut
/// keeps. With a level filter (`filter`: its gain shift) the filtered
/// level must lie below `v(N)` (`filtered_below`). The seed and the filter
/// told, the moments; `None` (the general rescan, `state` as it was) if
/// N or more entries lie above the smallest, the pixels read do not set
/// the level or the filtered level is not below `v(N)`. Every rescan of
/// these rules on the CANARY bench is of this kind: the level fell below
/// `low` while `v(N)` did not.
#[cold]
#[inline(never)]
fn level_below_low(
    rows: &WindowRows<'_>,
    window: &OpenWindow,
    calibrator: &Calibrator<'_>,
    (entries, rule, bound, filter): (&[Entry], &WindowRule, i32, Option<u8>),
    scratch: &mut [i32],
    state: &mut SubapertureState,
) -> Option<Moments> {
    let (front, back, capacity) = (window.front(), window.back(), window.capacity as usize);
    let (front, back) = (&entries[..front], &entries[capacity - back..capacity]);
    let held = front.len() + back.len();
    // Fewer than 1024 entries, for the packed coordinate sums (`SumsAbove`).
    if held < rule.n as usize || held >= MOST_FRONT {
        return None;
    }
    // `v(N)` is the smallest entry, in the back tier if it holds any (the
    // front's values are at or above the hint, the back's below it), if
    // fewer than N entries are above it; else the cut would have held.
    let lowest = if back.is_empty() { front } else { back };
    let (mut v, mut copies) = (i32::MAX, 0);
    for e in lowest {
        if e.value < v {
            (v, copies) = (e.value, 0);
        }
        copies += (e.value == v) as usize;
    }
    if held - copies >= rule.n as usize {
        return None;
    }
    let mut found = 0;
    let range = (bound, window.low);
    let all_rows = window.height as usize;
    let room = rows.each_between(window, calibrator, range, all_rows, |_, _, p| {
        let Some(slot) = scratch.get_mut(found) else {
            return false;
        };
        *slot = p;
        found += 1;
        true
    });
    if !room {
        return None;
    }
    let (cutoff, l) = level_from_below(rule.rule, &mut scratch[..found], v, 0)?;
    let l = match filter {
        Some(gain_shift) => filtered_below(&mut state.level, l, gain_shift, v)?,
        None => l,
    };
    state.seed.observe(cutoff, true);
    // Every entry weighs `p - l` (each is above `i32::MIN`).
    let (f, b) = (
        centroid::sums_above(front, i32::MIN).moments(l),
        centroid::sums_above(back, i32::MIN).moments(l),
    );
    let moments = Moments {
        sum_w: f.sum_w + b.sum_w,
        sum_wi: f.sum_wi + b.sum_wi,
        sum_wj: f.sum_wj + b.sum_wj,
    };
    Some(moments)
}

/// Where a rescan looks first: as far below `low` as the seed's margin
/// (`hint - low`), and one more (a window whose seed was too high usually
/// missed its cutoff by less than that). Further down, the first attempt
/// keeps most of a window's background: 3 margins cost CANARY threshold
/// 0.13 instructions a pixel more on Cortex-M4; half a margin sent N = 5's
/// rescans to the second attempt (+0.2).
#[inline(always)]
pub(super) fn rescan_bound(low: i32, hint: i32) -> i32 {
    let margin = hint.saturating_sub(low).max(0);
    low.saturating_sub(margin).saturating_sub(1)
}

/// Where a rescanned window's raw pixels are: the frame pushed whole, or
/// the engine's row history.
pub(super) struct WindowRows<'h> {
    history: &'h [u16],
    history_rows: usize,
    whole_frame: usize,
    width: usize,
}

impl<'h> WindowRows<'h> {
    /// The current frame's rows: in the frame pushed whole (`whole_frame`,
    /// its first pixel's address; 0 if not), else in the `history` ring of
    /// `history_rows` camera rows.
    #[inline(always)]
    pub(super) fn new(
        history: &'h [u16],
        history_rows: usize,
        whole_frame: usize,
        config: &Config<'_>,
    ) -> Self {
        WindowRows {
            history,
            history_rows,
            whole_frame,
            width: config.camera.width as usize,
        }
    }

    /// Row `j` of `window` (one the frame has delivered), raw, and the
    /// row-major index of its first pixel.
    #[inline(always)]
    fn raw(&self, window: &OpenWindow, j: usize) -> (&[u16], usize) {
        let (x, w) = (window.x as usize, window.width as usize);
        let y = window.y as usize + j;
        let pixel = y * self.width + x;
        let raw = if self.whole_frame != 0 {
            // SAFETY: the frame is whole in the slice of the current call
            // to `push` (`whole_frame`), and the window lies in it.
            unsafe { core::slice::from_raw_parts((self.whole_frame as *const u16).add(pixel), w) }
        } else {
            let at = (y % self.history_rows) * self.width + x;
            &self.history[at..at + w]
        };
        (raw, pixel)
    }

    /// `keep(i, j, p)` for the window's pixels in `[bound, below)` of its
    /// first `rows` rows, calibrated, row after row; `false` as soon as
    /// `keep` returns `false`.
    #[inline(always)]
    fn each_between(
        &self,
        window: &OpenWindow,
        calibrator: &Calibrator<'_>,
        range: (i32, i32),
        rows: usize,
        mut keep: impl FnMut(usize, usize, i32) -> bool,
    ) -> bool {
        let floor = calibrator.raw_floor(window.bounds, range.0);
        (0..rows).all(|j| {
            let (raw, pixel) = self.raw(window, j);
            calibrator.each_in_range(raw, pixel, floor, range, |i, p| keep(i, j, p))
        })
    }

    /// The window's pixels in `[bound, below)` of its first `rows` rows,
    /// calibrated, into the first entries of `out` (with their positions),
    /// row after row; their number, or `None` if `out` cannot hold them.
    pub(super) fn between(
        &self,
        window: &OpenWindow,
        calibrator: &Calibrator<'_>,
        range: (i32, i32),
        rows: usize,
        out: &mut [Entry],
    ) -> Option<usize> {
        let mut kept = 0;
        let room = self.each_between(window, calibrator, range, rows, |i, j, p| {
            let Some(slot) = out.get_mut(kept) else {
                return false;
            };
            *slot = Entry {
                value: p,
                position: pack(i as u16, j as u16) as u32,
            };
            kept += 1;
            true
        });
        room.then_some(kept)
    }

    /// The window's pixels at or above `bound`, calibrated, into the first
    /// entries of `out` (which holds a whole window), with their positions,
    /// row after row; their number and how many equal `bound`.
    fn candidates(
        &self,
        window: &OpenWindow,
        calibrator: &Calibrator<'_>,
        bound: i32,
        out: &mut [Entry],
    ) -> (usize, u16) {
        // Calibrated values are below 2^26 in magnitude, so below
        // `i32::MAX`. `out` holds the largest window (`plan`): never `None`.
        let range = (bound, i32::MAX);
        let kept = self
            .between(window, calibrator, range, window.height as usize, out)
            .unwrap_or(0);
        let at_bound = out[..kept].iter().filter(|e| e.value == bound).count();
        (kept, at_bound as u16)
    }
}

/// Never used: see `Engine::finish`.
const KEEPS_NOTHING: Cut = Cut {
    bound: i32::MAX,
    strict: true,
    level: None,
    cutoff: i32::MIN,
};
