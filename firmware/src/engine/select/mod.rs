//! Stage 2: selection of a window's brightest pixels (SPEC.md §3), from a
//! set of *candidates*.
//!
//! An open window keeps the pixels seen so far whose calibrated value is at
//! or above its admission threshold `low`, sorted into four *tiers* around a
//! second value, the *hint* (`low <= hint`), the sub-aperture's cutoff in its
//! previous frame:
//!
//! | tier | pixels | kept as |
//! |---|---|---|
//! | front | `p > hint`, and some `p == hint` | value and position, in the candidate buffer (from its start) |
//! | hint ties | the other `p == hint` | count and coordinate sums |
//! | back | `low <= p < hint`, but for the low ties | value and position, in the candidate buffer (from its end) |
//! | low ties | some `p == low` (when `low < hint`) | count and coordinate sums |
//!
//! The engine's scan puts pixels equal to a threshold into the buffer like
//! any other; only a compaction gathers them into a tie bucket. Pixels below
//! `low` are not kept. Invariant: every pixel seen so far at or above `low`
//! is in one tier. So the tiers hold the top of the window's sorted values
//! exactly, down to `low`, already partitioned at the hint.
//!
//! Everything a rule needs lies at or above a *cutoff* that only rises as
//! pixels arrive: `v(N+1)` for `subtract-next`, `v(N)` for `threshold`, the
//! level for `subtract-next-distinct`, the smallest averaged value for
//! `subtract-mean`. Since the spot changes little between frames, the cutoff
//! is usually the hint itself or close to it: the front then holds about N
//! pixels and the rule's order statistic is found in the hint ties or by a
//! short partial selection, never a sort.
//!
//! `low` (the hint less a margin, see [`super::seed`]) is a guess; pixels
//! below it are never calibrated, which is what makes the engine fast. As
//! soon as the front and hint ties alone prove the cutoff is at or above the
//! hint ([`Tiers::covers_hint`]), the back tier is dropped and `low` raised
//! to the hint, so the rest of the window is filtered harder. Two things can
//! go wrong, and neither changes a result:
//! - the buffer fills: [`Buffer::compact`] raises `low` to the cutoff of the
//!   candidates so far, dropping only values no rule can need any more; if
//!   nothing can be dropped the window is marked for a rescan;
//! - `low` was too high, so at the window's end the candidates do not reach
//!   the cutoff: the window is *rescanned* from the engine's row history,
//!   every pixel this time (see `stream/finish.rs`).

use super::centroid::Moments;
use brightpix_protocol::SelectionRule;

mod buffer;
mod one_pass;

pub use buffer::Buffer;
pub use one_pass::{
    largest_and_next, largest_and_next_counting, largest_and_next_skipping, two_lowest_above,
    two_lowest_above_counting, two_lowest_above_skipping, LargestAndNext, TwoLowest,
};

/// Bits of the column in a packed window position `(j << 6) | i`.
pub const COLUMN_BITS: u16 = 6;
const COLUMN_MASK: u16 = (1 << COLUMN_BITS) - 1;

/// A window position `(i, j)` packed into 12 bits.
#[inline(always)]
pub fn pack(i: u16, j: u16) -> u16 {
    (j << COLUMN_BITS) | i
}

#[inline(always)]
fn column(position: u16) -> u16 {
    position & COLUMN_MASK
}

#[inline(always)]
pub(crate) fn row(position: u16) -> u16 {
    position >> COLUMN_BITS
}

/// A candidate: its calibrated value and packed window position, side by
/// side so that one store (`STRD` on Cortex-M) keeps both.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[repr(C)]
pub struct Entry {
    pub value: i32,
    pub position: u32,
}

impl Entry {
    pub const ZERO: Entry = Entry {
        value: 0,
        position: 0,
    };

    /// The entry's bytes as one word, for one store of both fields where
    /// the compiler makes two of a struct's.
    #[inline(always)]
    pub fn word(value: i32, position: u32) -> u64 {
        // SAFETY: `repr(C)`, two 4-byte fields and no padding: eight bytes,
        // any of which make a `u64`.
        unsafe { core::mem::transmute(Entry { value, position }) }
    }
}

/// The selection parameters of one window.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WindowRule {
    pub rule: SelectionRule,
    /// N (`1 <= N < pixels`).
    pub n: u16,
    /// Pixels in the window.
    pub pixels: u16,
}

/// The fewest candidate buffer entries a window of `pixels` pixels
/// selecting `n` with `rule` is given: 0 without selection (`N >= pixels`,
/// SPEC.md §3).
///
/// About twice what the rule needs, so that a `low` a little low fills it
/// rarely and a compaction frees at least half of it; never more than the
/// window's pixels (then it never fills).
pub fn least_capacity(rule: SelectionRule, n: u16, pixels: usize) -> u16 {
    capacity(rule, n, pixels, 2, 32)
}

/// The candidate buffer entries a window is given when the pool has room
/// (see `plan`): about four times what the rule needs. A full buffer costs
/// a compaction (a selection over the candidates so far) and sends the
/// window's segments down the general path until it has room again; twice
/// the room measured 2.0 fewer instructions per pixel on CANARY
/// (subtract-next N = 20, Cortex-M4) and 4.2 fewer for subtract-next-distinct.
///
/// `subtract-next-distinct` gets eight times: its cutoff, the level below
/// `v(N)`, lies a count level below `subtract-next`'s `v(N+1)` where `v(N)`
/// has copies, so its windows admit from one level deeper (~80 admissions
/// a CANARY window against ~53), and a window whose cutoff fell fills four
/// times: 10 of 392 CANARY windows were compacted, 1 with six times, none
/// with eight (Cortex-M4, instructions a pixel: 18.40 -> 18.07 -> 17.98).
/// `subtract-mean` (3 compactions in 392) gained nothing from six times.
pub fn preferred_capacity(rule: SelectionRule, n: u16, pixels: usize) -> u16 {
    if rule == SelectionRule::SubtractNextDistinct {
        preferred_capacity_of::<true>(rule, n, pixels)
    } else {
        preferred_capacity_of::<false>(rule, n, pixels)
    }
}

/// [`preferred_capacity`] for a `rule` that is `subtract-next-distinct`
/// (`DISTINCT`) or is not, as the caller knows: the engine opens windows
/// in one instance of its loop for each (`Engine::open_windows`), and a
/// test of the rule in the loop cost the other rules' openings registers
/// (Cortex-M4 CANARY +0.03 to +0.06 instructions a pixel).
#[inline(always)]
pub(crate) fn preferred_capacity_of<const DISTINCT: bool>(
    rule: SelectionRule,
    n: u16,
    pixels: usize,
) -> u16 {
    debug_assert_eq!(DISTINCT, rule == SelectionRule::SubtractNextDistinct);
    capacity(rule, n, pixels, if DISTINCT { 8 } else { 4 }, 64)
}

fn capacity(rule: SelectionRule, n: u16, pixels: usize, times: usize, plus: usize) -> u16 {
    if n as usize >= pixels {
        return 0;
    }
    let needed = n as usize + below_count(rule);
    (times * needed + plus).min(pixels) as u16
}

/// Values below `v(N)` a rule uses.
fn below_count(rule: SelectionRule) -> usize {
    match rule {
        SelectionRule::SubtractMean { count } => count as usize,
        SelectionRule::Threshold => 0,
        _ => 1,
    }
}

/// Pixels of one value that are not in the buffer: their count and
/// coordinate sums.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Ties {
    pub count: u16,
    pub sum_i: u32,
    pub sum_j: u32,
}

impl Ties {
    pub const NONE: Ties = Ties {
        count: 0,
        sum_i: 0,
        sum_j: 0,
    };

    #[inline(always)]
    pub fn add(&mut self, position: u16) {
        self.count += 1;
        self.sum_i += column(position) as u32;
        self.sum_j += row(position) as u32;
    }
}

/// What the candidates say about a window: its kept set, its level, and the
/// cutoff below which no value matters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Cut {
    /// Kept pixels are `p > bound` (`strict`, subtract-next) or `p >= bound`.
    pub bound: i32,
    pub strict: bool,
    /// The instantaneous level `l` (SPEC.md §3); `None`: nothing subtracted.
    pub level: Option<i32>,
    /// Every value the rule used is at or above this; values below it can
    /// never matter, whatever pixels come next.
    pub cutoff: i32,
}

impl Cut {
    #[inline(always)]
    pub fn keeps(&self, p: i32) -> bool {
        p >= self.lowest_kept()
    }

    /// The smallest value kept (`bound + 1` when strict; a strict bound of
    /// `i32::MAX` keeps nothing, and no value reaches `i32::MAX`).
    #[inline(always)]
    pub fn lowest_kept(&self) -> i32 {
        self.bound.saturating_add(self.strict as i32)
    }
}

/// The candidates do not reach the cutoff: some value the rule needs is
/// below the admission threshold.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TooShallow;

/// A window's candidates, tier by tier (see the module documentation):
/// `front` values `> hint`, `hint_ties` copies of `hint`, `back` values in
/// `(low, hint)`, `low_ties` copies of `low` (`low < hint`, or no low ties).
pub struct Tiers<'a> {
    pub front: &'a [Entry],
    /// Entries of `front` equal to the hint (the others are above it).
    pub front_at_hint: u16,
    pub hint: i32,
    pub hint_ties: u16,
    pub back: &'a [Entry],
    pub low: i32,
    pub low_ties: u16,
    /// No pixel of the window was left out: the tiers are all of it.
    pub complete: bool,
    /// For the queries that permute values: as long as the longer tier.
    pub scratch: &'a mut [i32],
}

impl Tiers<'_> {
    /// Whether the front and hint ties alone prove the rule's cutoff is at
    /// or above the hint (so nothing below the hint can matter): for a rule
    /// selecting `n`.
    #[inline(always)]
    pub fn covers_hint(rule: SelectionRule, n: u16, front: u16, hint_ties: u16) -> bool {
        let (n, front, hint_ties) = (n as u32, front as u32, hint_ties as u32);
        match rule {
            // v(N+1) >= hint.
            SelectionRule::SubtractNext => front + hint_ties > n,
            // v(N) >= hint.
            SelectionRule::Threshold => front + hint_ties >= n,
            // v(N) > hint, and hint itself is below v(N).
            SelectionRule::SubtractNextDistinct => front >= n && hint_ties >= 1,
            // v(N) > hint, and M copies of hint below v(N).
            SelectionRule::SubtractMean { count } => front >= n && hint_ties >= count as u32,
        }
    }

    /// Whether, once [`covers_hint`](Self::covers_hint) holds, more pixels
    /// equal to the hint can no longer matter (so admission can become
    /// `p > hint`): their count is only needed up to what the front and hint
    /// ties already prove, and they are not kept, since the kept set is then
    /// above the hint. Not so for `threshold` while `v(N)` may be the hint.
    #[inline(always)]
    pub fn hint_ties_settled(rule: SelectionRule, n: u16, front: u16) -> bool {
        match rule {
            SelectionRule::Threshold => front >= n,
            _ => true,
        }
    }

    /// The k-th largest candidate (1-based), duplicates counted.
    fn kth_largest(&mut self, k: usize) -> Result<i32, TooShallow> {
        let front = self.front.len();
        let above = front - self.front_at_hint as usize;
        let hint = front + self.hint_ties as usize;
        let back = hint + self.back.len();
        if k <= above {
            if self.front_at_hint == 0 {
                Ok(kth_largest(self.front, k, self.scratch))
            } else {
                // Among the front's values above the hint.
                let mut len = 0;
                for e in self.front {
                    if e.value > self.hint {
                        self.scratch[len] = e.value;
                        len += 1;
                    }
                }
                Ok(kth_largest_in_place(&mut self.scratch[..len], k))
            }
        } else if k <= hint {
            Ok(self.hint)
        } else if k <= back {
            Ok(kth_largest(self.back, k - hint, self.scratch))
        } else if k <= back + self.low_ties as usize {
            Ok(self.low)
        } else {
            Err(TooShallow)
        }
    }

    /// The largest candidate strictly below `v`.
    fn largest_below(&self, v: i32) -> Option<i32> {
        let below = |entries: &[Entry]| entries.iter().map(|e| e.value).filter(|&x| x < v).max();
        below(self.front)
            .or((self.hint_ties > 0 && self.hint < v).then_some(self.hint))
            .or_else(|| below(self.back))
            .or((self.low_ties > 0 && self.low < v).then_some(self.low))
    }

    /// Front entries above the hint.
    fn above(&self) -> usize {
        self.front.len() - self.front_at_hint as usize
    }

    /// The `m` smallest front values above the hint, ascending, in one
    /// pass (`m <= NEAR_FRONT`): with `m = above - k + 1` the last is the
    /// k-th largest candidate, and every front value below it is among
    /// them.
    fn smallest_above_hint(&self, m: usize) -> [i32; NEAR_FRONT] {
        let hint = self.hint;
        let mut best = [0i32; NEAR_FRONT];
        let mut filled = 0usize;
        for e in self.front {
            let x = e.value;
            if x <= hint {
                continue;
            }
            if filled == m {
                if x >= best[m - 1] {
                    continue;
                }
                filled -= 1;
            }
            let mut at = filled;
            while at > 0 && x < best[at - 1] {
                best[at] = best[at - 1];
                at -= 1;
            }
            best[at] = x;
            filled += 1;
        }
        best
    }

    /// `(m, smallest)` if the k-th largest candidate is among the front's
    /// values above the hint and [`smallest_above_hint`](Self::smallest_above_hint)
    /// can find it.
    fn near_front(&self, k: usize) -> Option<(usize, [i32; NEAR_FRONT])> {
        let above = self.above();
        (k <= above && above - k < NEAR_FRONT).then(|| {
            let m = above - k + 1;
            (m, self.smallest_above_hint(m))
        })
    }

    /// The largest candidate at or below the hint (all of them are below
    /// any front value above it).
    fn largest_from_hint(&self) -> Option<i32> {
        if self.front_at_hint > 0 || self.hint_ties > 0 {
            return Some(self.hint);
        }
        self.back
            .iter()
            .map(|e| e.value)
            .max()
            .or((self.low_ties > 0).then_some(self.low))
    }

    /// The sum of the `m` largest candidates strictly below `v` (or of all
    /// of them if fewer), how many that is, and the smallest of them (`v`
    /// if none). The tiers are in decreasing order, so they are taken from
    /// in turn.
    fn top_below(&mut self, v: i32, m: usize) -> (i64, usize, i32) {
        let mut top = Top {
            v,
            m,
            sum: 0,
            taken: 0,
            smallest: v,
        };
        top.values(self.front, self.scratch);
        top.ties(self.hint, self.hint_ties);
        top.values(self.back, self.scratch);
        top.ties(self.low, self.low_ties);
        (top.sum, top.taken, top.smallest)
    }
}

impl Tiers<'_> {
    /// [`top_below`](Self::top_below) when `below` holds, ascending, every
    /// front value above the hint that is below `v` (and maybe copies of
    /// `v`): they first, the largest first, then the hint's copies in the
    /// front and its tie bucket, then the back and the low ties.
    fn top_below_near(&mut self, v: i32, m: usize, below: &[i32]) -> (i64, usize, i32) {
        let mut top = Top {
            v,
            m,
            sum: 0,
            taken: 0,
            smallest: v,
        };
        for &x in below.iter().rev().filter(|&&x| x < v) {
            if top.taken == m {
                break;
            }
            top.sum += x as i64;
            top.taken += 1;
            top.smallest = x;
        }
        top.ties(self.hint, self.front_at_hint + self.hint_ties);
        top.values(self.back, self.scratch);
        top.ties(self.low, self.low_ties);
        (top.sum, top.taken, top.smallest)
    }
}

/// The running state of [`Tiers::top_below`].
struct Top {
    v: i32,
    m: usize,
    sum: i64,
    taken: usize,
    smallest: i32,
}

impl Top {
    fn values(&mut self, entries: &[Entry], scratch: &mut [i32]) {
        // The values below v, copied.
        let mut len = 0;
        for x in entries.iter().map(|e| e.value) {
            if x < self.v {
                scratch[len] = x;
                len += 1;
            }
        }
        let want = (self.m - self.taken).min(len);
        if want == 0 {
            return;
        }
        let (sum, w) = sum_of_largest_in_place(&mut scratch[..len], want);
        self.sum += sum as i64;
        self.taken += want;
        self.smallest = w;
    }

    fn ties(&mut self, value: i32, count: u16) {
        let want = (self.m - self.taken).min(count as usize);
        if want == 0 || value >= self.v {
            return;
        }
        self.sum += value as i64 * want as i64;
        self.taken += want;
        self.smallest = value;
    }
}

/// The k-th largest value of `entries` (1-based, `k <= len`).
///
/// Near either end (the usual case: the cutoff is close to the hint) by one
/// pass that keeps the few extreme values in a small sorted array; else by
/// `select_nth_unstable` on a copy in `scratch` (at least `len` entries).
pub fn kth_largest(entries: &[Entry], k: usize, scratch: &mut [i32]) -> i32 {
    let len = entries.len();
    if k <= NEAR {
        extreme::<true>(entries.iter().map(|e| e.value), k)
    } else if len - k < NEAR {
        extreme::<false>(entries.iter().map(|e| e.value), len - k + 1)
    } else {
        let copy = &mut scratch[..len];
        for (c, e) in copy.iter_mut().zip(entries) {
            *c = e.value;
        }
        *copy.select_nth_unstable(len - k).1
    }
}

/// As [`kth_largest`], permuting `values` instead of copying them.
fn kth_largest_in_place(values: &mut [i32], k: usize) -> i32 {
    let len = values.len();
    if k <= NEAR || len - k < NEAR {
        kth_largest_near_ends(values, k)
    } else {
        *values.select_nth_unstable(len - k).1
    }
}

/// The sum of the `k` largest of `values` (`1 <= k <= values.len()`,
/// duplicates counted) and the smallest of them: a level rule's `k` values
/// below `v(N)`. Up to [`NEAR`] in one pass ([`extremes`]: `values` holds a
/// few values when the cutoff is near the hint); else those above the k-th
/// largest `w` and copies of `w`, after permuting `values`. The sum in 32
/// bits: `k <= 16` values (`MAX_MEAN_COUNT`) of `|p| < 2^25` (SPEC.md §2).
pub(crate) fn sum_of_largest_in_place(values: &mut [i32], k: usize) -> (i32, i32) {
    if k <= NEAR {
        let largest = extremes::<true, i32>(values.iter().copied(), |p| p, k);
        return (largest[..k].iter().sum(), largest[k - 1]);
    }
    let w = kth_largest_in_place(values, k);
    let (above, count) = values
        .iter()
        .filter(|&&p| p > w)
        .fold((0i32, 0usize), |(s, c), &p| (s + p, c + 1));
    (above + w * (k - count) as i32, w)
}

/// Within this many of either end, [`kth_largest`] keeps a small sorted
/// array in one pass.
pub(crate) const NEAR: usize = 8;

/// Within this many of the front's smallest value above the hint, [`cut`]
/// finds its order statistic in one pass over the front (see
/// `Tiers::near_front`): the usual case, the cutoff being near the hint.
const NEAR_FRONT: usize = 16;

fn kth_largest_near_ends(values: &[i32], k: usize) -> i32 {
    if k <= NEAR {
        extreme::<true>(values.iter().copied(), k)
    } else {
        extreme::<false>(values.iter().copied(), values.len() - k + 1)
    }
}

/// The m-th largest (`LARGEST`) or smallest of `values`, `1 <= m <= 8`.
#[inline(always)]
pub(crate) fn extreme<const LARGEST: bool>(values: impl Iterator<Item = i32>, m: usize) -> i32 {
    extremes::<LARGEST, i32>(values, |x| x, m)[m - 1]
}

/// The `m` largest (`LARGEST`) or smallest of `items` by `key`, from most
/// to least extreme (`1 <= m <= 8`, at least `m` items), in one pass that
/// keeps them in a small sorted array (its first `m`; the rest is
/// unspecified).
#[inline(always)]
pub(crate) fn extremes<const LARGEST: bool, T: Copy + Default>(
    items: impl Iterator<Item = T>,
    key: impl Fn(T) -> i32,
    m: usize,
) -> [T; 8] {
    // best[..filled] sorted from most to least extreme. An array of
    // entries starts as eight copies of the first item, not zeroed: eight
    // stores, where zeroing its 64 bytes was a `memclr` call (~40
    // instructions on Cortex-M4, about once a window's end). An array of
    // values is zeroed inline: taking their first item apart from the loop
    // cost more than that (the complement's chained iterators: N = 200
    // +0.5 instructions a pixel).
    let mut items = items;
    let (mut best, mut filled) = if core::mem::size_of::<T>() > 4 {
        match items.next() {
            Some(first) => ([first; 8], 1usize),
            None => return [T::default(); 8],
        }
    } else {
        ([T::default(); 8], 0usize)
    };
    let beats = |a: i32, b: i32| if LARGEST { a > b } else { a < b };
    for x in items {
        let kx = key(x);
        if filled == m {
            if !beats(kx, key(best[m - 1])) {
                continue;
            }
            filled -= 1;
        }
        let mut at = filled;
        while at > 0 && beats(kx, key(best[at - 1])) {
            best[at] = best[at - 1];
            at -= 1;
        }
        best[at] = x;
        filled += 1;
    }
    best
}

/// The kept set, level and cutoff of `rule` over the candidates (SPEC.md §3).
///
/// With `complete` false the result holds for the whole window only if it
/// is `Ok`; with `complete` true it is always `Ok`.
pub fn cut(rule: &WindowRule, c: &mut Tiers<'_>) -> Result<Cut, TooShallow> {
    let n = rule.n as usize;
    match rule.rule {
        SelectionRule::SubtractNext => {
            let v = match c.near_front(n + 1) {
                Some((m, smallest)) => smallest[m - 1],
                None => c.kth_largest(n + 1)?,
            };
            Ok(Cut {
                bound: v,
                strict: true,
                level: Some(v),
                cutoff: v,
            })
        }
        SelectionRule::Threshold => {
            let v = match c.near_front(n) {
                Some((m, smallest)) => smallest[m - 1],
                None => c.kth_largest(n)?,
            };
            Ok(Cut {
                bound: v,
                strict: false,
                level: None,
                cutoff: v,
            })
        }
        SelectionRule::SubtractNextDistinct => {
            let (v, l) = match c.near_front(n) {
                // Every front value below v is among the smallest; the rest
                // of the candidates are at or below the hint.
                Some((m, smallest)) => {
                    let v = smallest[m - 1];
                    let below = smallest[..m - 1].iter().rev().find(|&&x| x < v).copied();
                    (v, below.or_else(|| c.largest_from_hint()))
                }
                None => {
                    let v = c.kth_largest(n)?;
                    (v, c.largest_below(v))
                }
            };
            match l {
                Some(l) => Ok(Cut {
                    bound: v,
                    strict: false,
                    level: Some(l),
                    cutoff: l,
                }),
                None if c.complete => Ok(Cut {
                    bound: v,
                    strict: false,
                    level: None,
                    cutoff: v,
                }),
                None => Err(TooShallow),
            }
        }
        SelectionRule::SubtractMean { count } => {
            let m = count as usize;
            let (v, (sum, taken, smallest)) = match c.near_front(n) {
                Some((len, values)) => {
                    let v = values[len - 1];
                    (v, c.top_below_near(v, m, &values[..len - 1]))
                }
                None => {
                    let v = c.kth_largest(n)?;
                    (v, c.top_below(v, m))
                }
            };
            if taken < m && !c.complete {
                return Err(TooShallow);
            }
            Ok(Cut {
                bound: v,
                strict: false,
                // `taken <= 16` values of `|p| < 2^25`: the sum fits 32
                // bits, and a 32-bit division is `sdiv` on Cortex-M.
                level: (taken > 0).then(|| (sum as i32).div_euclid(taken as i32)),
                cutoff: smallest,
            })
        }
    }
}

/// The weights of `cut` (with `level`, the filtered level, for subtracting
/// rules) reduced to centre-of-gravity moments over candidates.
#[inline(always)]
pub fn add_moments(moments: &mut Moments, cut: &Cut, level: Option<i32>, entries: &[Entry]) {
    let lowest = cut.lowest_kept();
    match level {
        Some(level) => {
            // Weights max(0, p - level) are never negative: sums of u32
            // products in u64 (one multiply-accumulate each on Cortex-M).
            // |p|, |level| < 2^25, so p - level does not overflow.
            let (mut f, mut wi, mut wj) = (0u64, 0u64, 0u64);
            for e in entries {
                if e.value >= lowest {
                    let w = e.value.wrapping_sub(level).max(0) as u32;
                    let position = e.position;
                    f += w as u64;
                    wi += w as u64 * (position & COLUMN_MASK as u32) as u64;
                    wj += w as u64 * ((position >> COLUMN_BITS) & COLUMN_MASK as u32) as u64;
                }
            }
            moments.sum_w += f as i64;
            moments.sum_wi += wi as i64;
            moments.sum_wj += wj as i64;
        }
        None => {
            for e in entries {
                if e.value >= lowest {
                    let position = e.position as u16;
                    moments.add(e.value, column(position), row(position));
                }
            }
        }
    }
}

/// The tie bucket's share of the moments (see [`add_moments`]).
#[inline(always)]
pub fn add_tie_moments(
    moments: &mut Moments,
    cut: &Cut,
    level: Option<i32>,
    value: i32,
    ties: Ties,
) {
    if ties.count > 0 && cut.keeps(value) {
        let w = match level {
            Some(level) => (value - level).max(0),
            None => value,
        };
        moments.add_group(w, ties.count, ties.sum_i, ties.sum_j);
    }
}
