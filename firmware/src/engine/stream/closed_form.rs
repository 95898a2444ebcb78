//! A window's cutoff and moments in closed form.
//! For `subtract-next`, the windows without low ties whose candidates
//! reach `v(N+1)`: the weights are `p - v` over `p > v`, so
//!
//! `sum (p - v) i = sum p i - v sum i`
//!
//! (and likewise for `j` and the plain sum) over the pixels above `v`,
//! from sums taken in one pass ([`centroid::sums_above`]). Two cases:
//! - the front with the hint's ties reaches `v(N+1)` (the usual case): the
//!   sums over the front's values above the hint, less the few between the
//!   hint and `v`. `v(N+1)` is the hint if at most N values are above it,
//!   else the `(count - N)`-th smallest of them, found by a second pass
//!   keeping the smallest few, whole, which are also the ones to take back
//!   out (or, deeper, a selection on a copy and a third pass);
//! - the front falls short (the spot dimmed or moved since the hint was
//!   set: about a fifth of CANARY's windows): `v(N+1)` is among the back
//!   tier's values, found by one pass keeping its largest few, which are
//!   also its pixels above `v(N+1)`; the front's sums weigh whole
//!   ([`cutoff_in_back`]).
//!
//! `threshold` (`threshold_end`) uses the same sums at a level of 0: its
//! kept pixels `p >= v(N)` weigh `p`, so ties with `v(N)` weigh too.
//! `subtract-next-distinct` and `subtract-mean` (`level_rule_end`) keep
//! `p >= v(N)` and weigh `p - level`, the level below `v(N)`: the same
//! sums above `v(N) - 1` at their level, once the few values below `v(N)`
//! that set it are found.
//!
//! With a level filter (SPEC.md §4) the cutoff and the instantaneous level
//! are found the same way, the filter's state is updated from that level
//! and the moments are taken at the filtered level `L` instead. For
//! `subtract-next` the pixels weighing are those above `max(v, L)`, each
//! `p - L` (`moments_at_level`: the sums' closed form at `L`, less the
//! pixels from the hint up to `max(v, L)`, found by a pass over the front
//! unless `L = v`). For the level rules every kept pixel weighs `p - L` if
//! `L < v(N)`; otherwise (the level jumped) the window ends the ordinary
//! way, the filter's state as it was ([`filtered_below`]).
//!
//! Exact integer identities: the result is the ordinary end's bit for
//! bit. The frame's last row (`last_row`) keeps such sums too, for the
//! pixels above `v(N+1)` of the candidates so far, and ends its windows
//! with the same arithmetic ([`cutoff_and_moments`]).

use super::admission::settle_at_hint;
use super::{Engine, OutputSink};
use crate::engine::centroid::{self, Moments, SumsAbove};
use crate::engine::select::{self, Entry};
use crate::engine::window::OpenWindow;
use crate::engine::LevelFilterState;
use brightpix_protocol::SelectionRule;

/// Below this many front entries the coordinate sums of the pixels above
/// the hint (each coordinate below 64) fit 16 bits each, packed in one
/// word ([`SumsAbove`]).
pub(super) const MOST_FRONT: usize = 1024;

/// A front longer than N by more than this ends the ordinary way: the
/// cutoff may then lie deep among the values above the hint, and the
/// ordinary end's selection and one pass over what it keeps beat the
/// closed form's sums, selection and correction (Cortex-M4, instructions a
/// pixel: CANARY N = 200 41.17 with 32, 42.61 with 64; N = 60 18.80 with
/// 16, 18.41 with 32).
const MOST_ABOVE_N: usize = 32;

/// Up to this deep among the pixels above `u`, `v(N+1)` is found in one
/// pass keeping the smallest (`select::extremes`, whole entries when there
/// is no last row's part, so that they also give the pixels between `u`
/// and `v`); deeper, by a selection on a copy of their values.
const MOST_SMALLEST: usize = 8;

/// `v(N+1)` and the moments of a window whose candidates reach `v(N+1)`
/// and whose pixels above `u` are `before`'s above `u` (summed in `sums`)
/// and all of `last` (every one above `u`), with `v(N+1) >= u`. `v(N+1)`
/// is `u` if at most N pixels are above it, else the `(above - N)`-th
/// smallest above it. `level` gives the level to subtract from `v(N+1)`:
/// `v(N+1)` itself, or (`FILTERED`) the level filter's (SPEC.md §4). At `v` the moments
/// are the sums' closed form, less `before`'s pixels between `u` and `v`
/// (summed with a negative weight), plus `last`'s above `v`; at another
/// level, [`moments_at_level`]. `scratch` holds at least as many values as
/// `before` and `last` together.
#[inline(always)]
pub(super) fn cutoff_and_moments<const FILTERED: bool>(
    u: i32,
    sums: &SumsAbove,
    before: &[Entry],
    last: &[Entry],
    n: usize,
    scratch: &mut [i32],
    level: impl FnOnce(i32) -> i32,
) -> (i32, Moments) {
    let above = sums.count as usize + last.len();
    if above > n && above - n <= MOST_SMALLEST && last.is_empty() {
        // The `m` smallest entries above `u`, kept whole: `v` is the last,
        // and the entries between `u` and `v` are among the others, so
        // no second pass over `before` takes them back out (with a
        // filtered level, copies of `v` beyond them and pixels up to a
        // level above `v` may weigh: a second pass).
        let m = above - n;
        let smallest = select::extremes::<false, Entry>(
            before.iter().copied().filter(|e| e.value > u),
            |e| e.value,
            m,
        );
        let v = smallest[m - 1].value;
        let l = level(v);
        if l != v {
            return (v, moments_at_level::<FILTERED>(u, sums, before, last, v, l));
        }
        let mut moments = sums.moments(v);
        for e in smallest[..m - 1].iter().filter(|e| e.value < v) {
            weigh(&mut moments, e, v as i64, -1);
        }
        return (v, moments);
    }
    let values = before
        .iter()
        .map(|e| e.value)
        .filter(|&p| p > u)
        .chain(last.iter().map(|e| e.value));
    let v = if above <= n {
        u
    } else if above - n <= MOST_SMALLEST {
        select::extreme::<false>(values, above - n)
    } else {
        let copy = &mut scratch[..above];
        for (c, p) in copy.iter_mut().zip(values) {
            *c = p;
        }
        *copy.select_nth_unstable(above - n - 1).1
    };
    (
        v,
        moments_at_level::<FILTERED>(u, sums, before, last, v, level(v)),
    )
}

/// The moments of `p - l` over the pixels above `max(v, l)`, those of
/// [`cutoff_and_moments`]'s window: the kept pixels `p > v` weighing
/// `max(0, p - l)` (SPEC.md §3-4). The sums' closed form at `l`, less
/// `before`'s pixels between `u` and `max(v, l)`, plus `last`'s above it;
/// with `l = v`, as the ordinary end at `v(N+1)`.
#[inline(always)]
fn moments_at_level<const FILTERED: bool>(
    u: i32,
    sums: &SumsAbove,
    before: &[Entry],
    last: &[Entry],
    v: i32,
    l: i32,
) -> Moments {
    let (c, l64) = (v.max(l), l as i64);
    let mut moments = sums.moments(l);
    if c > u {
        // A pixel at `l` weighs 0: without a filter, `v`'s copies, left
        // out (they may be many); with one, weighed (a test less).
        for e in before
            .iter()
            .filter(|e| e.value > u && e.value <= c && (FILTERED || e.value != l))
        {
            weigh(&mut moments, e, l64, -1);
        }
    }
    for e in last.iter().filter(|e| e.value > c) {
        weigh(&mut moments, e, l64, 1);
    }
    moments
}

/// Whether the front of `window` (which selects, and has no low ties)
/// with the hint's ties reaches `v(N+1)`, so that it is at or above the
/// hint and nothing below the hint weighs, and the front is short enough
/// for [`cutoff_and_moments`].
#[inline(always)]
fn front_reaches_cutoff(window: &OpenWindow) -> bool {
    window.front() <= window.n as usize + MOST_ABOVE_N
        && window.front() + window.hint_ties.count as usize > window.n as usize
}

/// `v(N+1)` and the moments of `window` (which selects, and has no low
/// ties) when `v(N+1)` lies in its back tier: the front, `F` pixels with
/// no hint ties, falls short of N + 1, so `v(N+1)` is the `(N + 1 - F)`-th
/// largest of the back's values, if the back has that many (`None` if
/// not). Below the hint, it leaves every front pixel weighing: the front's
/// sums in closed form ([`SumsAbove`]) and the back's pixels above
/// `v(N+1)`, which the pass that finds it keeps when it is among the
/// back's few largest.
#[inline(always)]
fn cutoff_in_back(
    window: &OpenWindow,
    scratch: &mut [i32],
    level: impl FnOnce(i32) -> i32,
) -> Option<(i32, Moments)> {
    let (front, back, n) = (window.front(), window.back(), window.n as usize);
    // Hint ties come only with `low` raised to the hint (a compaction's or
    // `raise_to_hint`'s), which empties the back.
    if window.hint_ties.count != 0 || front > n || n + 1 - front > back {
        return None;
    }
    let k = n + 1 - front;
    // SAFETY: the window's buffer (opened with it), no other reference to
    // it alive.
    let entries: &[Entry] = unsafe { window.entries() };
    let capacity = window.capacity as usize;
    let back = &entries[capacity - back..capacity];
    let front = &entries[..front];
    // With a filtered level `l` above `v`, the pixels weighing are those
    // above `l` (`c`): the front's above it, and the back's, which are
    // also above `v`, so among its `k - 1` largest.
    Some(if k <= MOST_SMALLEST {
        let largest = select::extremes::<true, Entry>(back.iter().copied(), |e| e.value, k);
        let v = largest[k - 1].value;
        let l = level(v);
        let c = v.max(l);
        let mut moments = centroid::sums_above(front, c).moments(l);
        for e in largest[..k - 1].iter().filter(|e| e.value > c) {
            weigh(&mut moments, e, l as i64, 1);
        }
        (v, moments)
    } else {
        let v = select::kth_largest(back, k, scratch);
        let l = level(v);
        let c = v.max(l);
        let mut moments = centroid::sums_above(front, c).moments(l);
        for e in back.iter().filter(|e| e.value > c) {
            weigh(&mut moments, e, l as i64, 1);
        }
        (v, moments)
    })
}

/// `v(N)` and the moments of a `threshold` window (no low ties), whose
/// kept pixels `p >= v(N)` weigh `p`: the same sums at a level of 0.
/// - The front with the hint's ties reaches `v(N)` (`F + T >= N`): with
///   `A` front values above the hint, `v(N)` is the hint if `A < N`, and
///   every front pixel and hint tie is kept; else the `(A - N + 1)`-th
///   smallest above the hint, found by one pass keeping the smallest few
///   whole, which are also the pixels between the hint and `v(N)` to take
///   back out.
/// - Else `v(N)` is the `(N - F)`-th largest of the back's values (no hint
///   ties then, see [`cutoff_in_back`]), and the front and the back's
///   pixels at or above it are kept: ties with `v(N)` weigh too, so a
///   second pass over the back takes them.
///
/// `None` (the ordinary end) if `v(N)` lies deeper than that.
#[inline(always)]
fn threshold_end(window: &mut OpenWindow, scratch: &mut [i32]) -> Option<(i32, Moments)> {
    let (f, n, hint) = (window.front(), window.n as usize, window.hint);
    let ties = window.hint_ties;
    // SAFETY: the window's buffer (opened with it), no other reference to
    // it alive.
    let entries: &[Entry] = unsafe { window.entries() };
    let front = &entries[..f];
    if f + ties.count as usize >= n {
        settle_at_hint(window);
        let above = f - window.at_hint as usize;
        if above < n {
            // `hint - 1`: front values are at or above the hint, which is
            // above i32::MIN (the seed's cutoffs are below 2^26 in size).
            let mut moments = centroid::sums_above(front, hint.checked_sub(1)?).moments(0);
            moments.add_group(hint, ties.count, ties.sum_i, ties.sum_j);
            return Some((hint, moments));
        }
        let m = above - n + 1;
        if m > MOST_SMALLEST {
            return None;
        }
        let smallest = select::extremes::<false, Entry>(
            front.iter().copied().filter(|e| e.value > hint),
            |e| e.value,
            m,
        );
        let v = smallest[m - 1].value;
        let mut moments = centroid::sums_above(front, hint).moments(0);
        for e in smallest[..m - 1].iter().filter(|e| e.value < v) {
            weigh(&mut moments, e, 0, -1);
        }
        return Some((v, moments));
    }
    let back = window.back();
    if ties.count != 0 || n - f > back {
        return None;
    }
    let capacity = window.capacity as usize;
    let back = &entries[capacity - back..capacity];
    let v = select::kth_largest(back, n - f, scratch);
    let mut moments = centroid::sums_above(front, v).moments(0);
    for e in back.iter().filter(|e| e.value >= v) {
        weigh(&mut moments, e, 0, 1);
    }
    Some((v, moments))
}

/// The seed's cutoff and the moments of a `subtract-next-distinct` or
/// `subtract-mean` window, or `None` (the ordinary end). Both keep
/// `p >= v(N)` and weigh `p - level` with `level < v(N)`, so every kept
/// pixel weighs: the sums of the kept front pixels in closed form, in one
/// pass ([`centroid::sums_above`] at `v(N) - 1`).
/// - With `A >= N` front values above the hint, `v(N)` is the
///   `(A - N + 1)`-th smallest of them: one pass keeping the two smallest
///   values and their copies ([`nth_of_two_lowest`]), else one keeping
///   that many smallest (up to 8), else a selection on a copy. The level
///   comes from those below `v(N)` and, below them, the hint's copies (in
///   the front and the tie bucket).
/// - With fewer, but `N` or more with the hint's copies in the front,
///   `v(N)` is the hint: every front pixel is kept, and the level comes
///   from the back tier and, below it, the low ties.
/// - With fewer still, for `subtract-next-distinct` (whose hint is one
///   above the previous level, so that its copies are in the back),
///   `v(N)` may be the back's largest value ([`distinct_cutoff_in_back`]).
///
/// Anything else (`v(N)` deeper in the back tier, candidates that do not
/// reach the level) ends the ordinary way, which also rescans.
///
/// `level` gives the level to subtract from the instantaneous level and
/// `v(N)`: the instantaneous level, or the level filter's if it lies below
/// `v(N)` (so that every kept pixel weighs `p - L`); `None` ends the
/// window the ordinary way. It is called last, when nothing else can fail.
#[inline(always)]
fn level_rule_end(
    window: &mut OpenWindow,
    rule: SelectionRule,
    scratch: &mut [i32],
    level: impl FnOnce(i32, i32) -> Option<i32>,
) -> Option<(i32, Moments)> {
    settle_at_hint(window);
    let (f, n, hint, ties) = (
        window.front(),
        window.n as usize,
        window.hint,
        window.hint_ties,
    );
    let above = f - window.at_hint as usize;
    let copies = window.at_hint as usize + ties.count as usize;
    // SAFETY: the window's buffer (opened with it), no other reference to
    // it alive.
    let entries: &[Entry] = unsafe { window.entries() };
    let front = &entries[..f];
    if above < n {
        let capacity = window.capacity as usize;
        let back = &entries[capacity - window.back()..capacity];
        if above + copies < n {
            return if rule == SelectionRule::SubtractNextDistinct {
                distinct_cutoff_in_back(window, front, back, above + copies, level)
            } else {
                None
            };
        }
        // Hint ties come only with `low` raised to the hint (a
        // compaction's), which leaves no back tier: the level would lie
        // below every candidate.
        if ties.count != 0 {
            return None;
        }
        // `v(N)` is the hint: every front pixel is kept, and the level
        // comes from the back tier and the low ties.
        let below = &mut scratch[..back.len()];
        for (c, e) in below.iter_mut().zip(back) {
            *c = e.value;
        }
        let (cutoff, l) =
            level_from_below(rule, below, window.low, window.low_ties.count as usize)?;
        let sums = centroid::sums_above(front, hint.checked_sub(1)?);
        return Some((cutoff, sums.moments(level(l, hint)?)));
    }
    let m = above - n + 1;
    let (mut few, mut lowest);
    let (v, below) = if let Some((v, lower, copies)) = nth_of_two_lowest(front, hint, m) {
        lowest = [lower; 16];
        (v, &mut lowest[..copies.min(16)])
    } else if m <= MOST_SMALLEST {
        few = select::extremes::<false, i32>(
            front.iter().map(|e| e.value).filter(|&p| p > hint),
            |p| p,
            m,
        );
        (few[m - 1], &mut few[..m - 1])
    } else {
        let copy = &mut scratch[..above];
        let values = front.iter().map(|e| e.value).filter(|&p| p > hint);
        for (c, p) in copy.iter_mut().zip(values) {
            *c = p;
        }
        let (lower, &mut v, _) = copy.select_nth_unstable(m - 1);
        (v, lower)
    };
    // Those below `v(N)` (`below` may hold copies of it).
    let mut len = 0;
    for k in 0..below.len() {
        if below[k] < v {
            below[len] = below[k];
            len += 1;
        }
    }
    let (cutoff, l) = level_from_below(rule, &mut below[..len], hint, copies)?;
    let level = level(l, v)?;
    // `v - 1`: `v` is above the hint.
    Some((cutoff, centroid::sums_above(front, v - 1).moments(level)))
}

/// The `m`-th smallest of the front's values above `hint` when it is one
/// of the two smallest values there, with the smallest and its number of
/// copies if it is the second (else no copies): one pass keeping two
/// values and their copies ([`select::two_lowest_above`]). A level rule's
/// hint is a level below the previous `v(N)`, and the values just above
/// it are mostly copies of one or two values (ties at `v(N)` of a faint
/// spot's wings), where [`select::extremes`] would keep `m` of them (up to
/// 8) and a deeper cutoff (N = 60) took a selection on a copy. `None` if
/// the `m`-th lies deeper (spread values, a gain or background map).
#[inline(never)]
fn nth_of_two_lowest(front: &[Entry], hint: i32, m: usize) -> Option<(i32, i32, usize)> {
    let two = select::two_lowest_above(front, hint);
    let (v1, c1) = (two.lowest, two.lowest_copies);
    if c1 >= m {
        Some((v1, v1, 0))
    } else if c1 + two.second_copies >= m {
        Some((two.second, v1, c1))
    } else {
        None
    }
}

/// A `subtract-next-distinct` window whose `held` pixels at or above the
/// hint fall short of N (its hint one above the previous level,
/// `Engine::hint_above`, which a window whose cutoff did not fall passes
/// N times before its end): `v(N)` is the back tier's largest value `b`
/// if its copies make N, and the level the largest value below `b` in the
/// back. One pass over the back finds both and `b`'s copies
/// ([`select::largest_and_next`]), which are kept with every pixel at or
/// above the hint.
/// `None` (the ordinary end) if `b`'s copies fall short, nothing lies
/// below `b` in the back, or there are low ties. Out of line: inlined, it
/// cost `subtract-mean`'s end registers.
#[inline(never)]
fn distinct_cutoff_in_back(
    window: &OpenWindow,
    front: &[Entry],
    back: &[Entry],
    held: usize,
    level: impl FnOnce(i32, i32) -> Option<i32>,
) -> Option<(i32, Moments)> {
    // Low ties (after a compaction, rare) are left to the ordinary end.
    if window.low_ties.count != 0 {
        return None;
    }
    let select::LargestAndNext {
        largest: b,
        copies,
        next: below,
    } = select::largest_and_next(back);
    // A value below `b` held: `below`, unless it is still the marker (the
    // back's values are calibrated values, above `i32::MIN`).
    if copies.count == 0 || held + (copies.count as usize) < window.n as usize || below == i32::MIN
    {
        return None;
    }
    let ties = window.hint_ties;
    let l = level(below, b)?;
    // Every front value is at or above the hint, which is above `b`.
    let mut moments = centroid::sums_above(front, b).moments(l);
    moments.add_group(window.hint - l, ties.count, ties.sum_i, ties.sum_j);
    moments.add_group(b - l, copies.count, copies.sum_i, copies.sum_j);
    Some((below, moments))
}

/// The seed's cutoff and the level of `subtract-next-distinct` (the largest
/// value below `v(N)`) or `subtract-mean` (the floored mean of the M
/// largest below `v(N)`, the cutoff the smallest of them), from the
/// candidates below `v(N)`: `below` (any order; permuted), then `copies`
/// copies of `tie`, below all of them. `None` if they fall short.
#[inline(always)]
pub(super) fn level_from_below(
    rule: SelectionRule,
    below: &mut [i32],
    tie: i32,
    copies: usize,
) -> Option<(i32, i32)> {
    match rule {
        SelectionRule::SubtractNextDistinct => {
            let level = below
                .iter()
                .copied()
                .max()
                .or((copies > 0).then_some(tie))?;
            Some((level, level))
        }
        SelectionRule::SubtractMean { count } => {
            let m = count as usize;
            let taken = below.len().min(m);
            let from_tie = m - taken;
            if m == 0 || from_tie > copies {
                return None;
            }
            // In 32 bits: M <= 16 values, each `|p| < 2^25` (SPEC.md §2),
            // sum below 2^29 in magnitude; a 64-bit division is a library
            // call on Cortex-M (~65 instructions), a 32-bit one `sdiv`.
            let (mut sum, mut cutoff) = (from_tie as i32 * tie, tie);
            if taken > 0 {
                let (largest, w) = select::sum_of_largest_in_place(below, taken);
                sum += largest;
                if from_tie == 0 {
                    cutoff = w;
                }
            }
            Some((cutoff, sum.div_euclid(m as i32)))
        }
        _ => None,
    }
}

impl Engine<'_, '_> {
    /// The end of window `k`, which selects, in closed form (see the module
    /// documentation), for `subtract-next` or `threshold` (`FILTERED`:
    /// `subtract-next` with a level filter, its state updated from
    /// `v(N+1)` and the moments at its level): `false` (nothing done) if
    /// the ordinary end must compute it (a rescan, low ties, a long front,
    /// or a cutoff deeper than the closed forms reach). Out of line for
    /// the same reason as `finish_prepared`.
    #[inline(never)]
    pub(super) fn finish_in_closed_form<const FILTERED: bool>(
        &mut self,
        k: usize,
        sink: &mut impl OutputSink,
    ) -> bool {
        let memory = &mut self.memory;
        let window = &mut memory.open[k];
        if window.rescan || window.low_ties.count != 0 || window.front() >= MOST_FRONT {
            return false;
        }
        // Called once `v(N+1)` is known, when nothing can fail any more.
        let gain_shift = self.gain_shift;
        let (subapertures, index) = (&mut *memory.subapertures, window.index as usize);
        let level = |v| {
            if FILTERED {
                subapertures[index].level.filter(v, gain_shift)
            } else {
                v
            }
        };
        // A filter never comes with `threshold` here (`filtered_closed_form`).
        let end = if !FILTERED && self.config.selection.rule == SelectionRule::Threshold {
            threshold_end(window, memory.scratch)
        } else if front_reaches_cutoff(window) {
            // SAFETY: the window's buffer (opened with it), no other
            // reference to it alive.
            let entries: &[Entry] = unsafe { window.entries() };
            let front = &entries[..window.front()];
            let sums = centroid::sums_above(front, window.hint);
            Some(cutoff_and_moments::<FILTERED>(
                window.hint,
                &sums,
                front,
                &[],
                window.n as usize,
                memory.scratch,
                level,
            ))
        } else {
            cutoff_in_back(window, memory.scratch, level)
        };
        let Some((v, moments)) = end else {
            return false;
        };
        // `emit` counts the front and hint ties.
        let back = window.back() as u32;
        self.stats.candidates = self.stats.candidates.wrapping_add(back);
        self.emit(k, v, moments, sink);
        true
    }

    /// [`finish_in_closed_form`](Self::finish_in_closed_form) for
    /// `subtract-next-distinct` and `subtract-mean` ([`level_rule_end`]).
    /// A method of its own, so that `subtract-next`'s stays as lean (one
    /// more rule in it cost CANARY 0.03 instructions a pixel on Cortex-M4).
    #[inline(never)]
    pub(super) fn finish_level_rule_in_closed_form<const FILTERED: bool>(
        &mut self,
        k: usize,
        sink: &mut impl OutputSink,
    ) -> bool {
        let memory = &mut self.memory;
        let window = &mut memory.open[k];
        // Low ties are welcome: only the level may need them.
        if window.rescan || window.front() >= MOST_FRONT {
            return false;
        }
        let rule = self.config.selection.rule;
        // Two calls, so that without a filter the level is a closure with
        // nothing to carry (`distinct_cutoff_in_back` is out of line).
        let end = if FILTERED {
            let gain_shift = self.gain_shift;
            let state = &mut memory.subapertures[window.index as usize].level;
            level_rule_end(window, rule, memory.scratch, |l, cutoff| {
                filtered_below(state, l, gain_shift, cutoff)
            })
        } else {
            level_rule_end(window, rule, memory.scratch, |l, _| Some(l))
        };
        let Some((cutoff, moments)) = end else {
            return false;
        };
        let back = window.back() as u32;
        self.stats.candidates = self.stats.candidates.wrapping_add(back);
        self.emit(k, cutoff, moments, sink);
        true
    }

    /// The end of window `k`, which selects, in closed form with a level
    /// filter: `subtract-next`'s or the level rules'.
    #[inline(always)]
    pub(super) fn finish_filtered_in_closed_form(
        &mut self,
        k: usize,
        sink: &mut impl OutputSink,
    ) -> bool {
        if self.config.selection.rule == SelectionRule::SubtractNext {
            self.finish_in_closed_form::<true>(k, sink)
        } else {
            self.finish_level_rule_in_closed_form::<true>(k, sink)
        }
    }

    /// Window `k`'s end computed (`v(N+1)` and moments, by a closed form):
    /// the window closed, the seed told and the result out.
    #[inline(always)]
    pub(super) fn emit(&mut self, k: usize, v: i32, moments: Moments, sink: &mut impl OutputSink) {
        let window = &mut self.memory.open[k];
        self.finished_in_row = true;
        window.finished = true;
        self.stats.windows = self.stats.windows.wrapping_add(1);
        let held = window.front() + window.hint_ties.count as usize;
        self.stats.candidates = self.stats.candidates.wrapping_add(held as u32);
        self.memory.subapertures[window.index as usize]
            .seed
            .observe(v, false);
        sink.subaperture(self.centroider.result(
            window.index,
            moments,
            window.width,
            window.height,
        ));
    }
}

/// For `subtract-next-distinct` and `subtract-mean`, whose kept pixels are
/// at or above `cutoff` (`v(N)`): the filtered level from this frame's
/// level `l`, with `state` updated, if it lies below `cutoff`, so that
/// every kept pixel weighs `p - L` (SPEC.md §4); else `None`, `state` as
/// it was (the ordinary end then updates it and weighs `max(0, p - L)`).
#[inline(always)]
pub(super) fn filtered_below(
    state: &mut LevelFilterState,
    l: i32,
    gain_shift: u8,
    cutoff: i32,
) -> Option<i32> {
    let mut next = *state;
    let filtered = next.filter(l, gain_shift);
    (filtered < cutoff).then(|| {
        *state = next;
        filtered
    })
}

/// Adds (`sign` 1) or takes away (-1) `e`'s weight `p - v` in the moments.
#[inline(always)]
pub(super) fn weigh(moments: &mut Moments, e: &Entry, v: i64, sign: i64) {
    let w = sign * (e.value as i64 - v);
    moments.sum_w += w;
    moments.sum_wi += w * (e.position & 63) as i64;
    moments.sum_wj += w * ((e.position >> 6) & 63) as i64;
}
