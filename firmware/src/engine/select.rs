//! Stage 2: streaming selection of a window's brightest pixels (SPEC.md §3).
//!
//! Each open window keeps a min-heap of its `C` brightest calibrated values so
//! far (`C = N`, or `N + 1` for `subtract-next`) with their positions, in a
//! slot of the engine's pool. A pixel below the heap minimum is rejected with
//! one comparison, which is the common case once a window's heap is full;
//! the minimum is kept in the window's state, so a whole row segment below
//! it is rejected by one branch-free pass, without touching the pool.
//!
//! Ties are exact without buffering: pixels equal to the heap minimum that do
//! not fit in the heap go to a *tie bucket* (count and coordinate sums; their
//! value is the heap minimum). Whatever leaves the heap and bucket for good is
//! strictly below the final `v(N)` and is remembered only as the rule needs:
//! its maximum (`subtract-next-distinct`) or its `M` largest values in a
//! second small heap (`subtract-mean`). Invariants, for a full heap:
//! - every pixel `> min` is in the heap;
//! - the bucket holds exactly the pixels `== min` that are not in the heap
//!   (it is emptied into "below" whenever the minimum rises);
//! - "below" has seen exactly the other pixels.
//!
//! At the end of the window, the heap minimum is `v(C)` and heap + bucket is
//! `{p >= v(C)}`, which is all each rule needs.

use super::centroid::Moments;
use super::level_filter::LevelFilterState;
use brightpix_protocol::SelectionRule;

/// Lower than any calibrated value (|p| < 2^25): "nothing below".
const NOTHING: i32 = i32::MIN;

/// Bits of the column in a packed window position `(j << 6) | i`.
const COLUMN_BITS: u16 = 6;
const COLUMN_MASK: u16 = (1 << COLUMN_BITS) - 1;

#[inline(always)]
fn pack(i: u16, j: u16) -> u16 {
    (j << COLUMN_BITS) | i
}

/// How a rule treats the pixels around `v(N)`; resolved at compile time so
/// each rule gets its own hot loop.
pub trait Rule {
    const RULE: RuleKind;
    /// Heap entries beyond N.
    const EXTRA: u16 = match Self::RULE {
        RuleKind::SubtractNext => 1,
        _ => 0,
    };
    /// Whether pixels equal to `v(N)` beyond the heap are kept.
    const KEEPS_TIES: bool = !matches!(Self::RULE, RuleKind::SubtractNext);
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum RuleKind {
    Threshold,
    SubtractNext,
    SubtractNextDistinct,
    SubtractMean,
}

pub struct ThresholdRule;
pub struct SubtractNextRule;
pub struct SubtractNextDistinctRule;
pub struct SubtractMeanRule;
impl Rule for ThresholdRule {
    const RULE: RuleKind = RuleKind::Threshold;
}
impl Rule for SubtractNextRule {
    const RULE: RuleKind = RuleKind::SubtractNext;
}
impl Rule for SubtractNextDistinctRule {
    const RULE: RuleKind = RuleKind::SubtractNextDistinct;
}
impl Rule for SubtractMeanRule {
    const RULE: RuleKind = RuleKind::SubtractMean;
}

/// Heap capacity for a window of `pixels` pixels selecting `n`: 0 means no
/// selection (`N >= n`, SPEC.md §3).
pub fn heap_capacity(rule: SelectionRule, n: u16, pixels: usize) -> u16 {
    if n as usize >= pixels {
        0
    } else if rule == SelectionRule::SubtractNext {
        n + 1
    } else {
        n
    }
}

/// Pool entries beyond the heap: the "below" heap of `subtract-mean`.
pub fn below_capacity(rule: SelectionRule, heap_capacity: u16) -> u16 {
    match rule {
        SelectionRule::SubtractMean { count } if heap_capacity > 0 => count,
        _ => 0,
    }
}

/// The slot of the engine's pool that an open window uses.
pub struct Slot<'p> {
    pub heap_values: &'p mut [i32],
    pub heap_positions: &'p mut [u16],
    /// `subtract-mean`'s min-heap of the largest values below `v(N)`.
    pub below: &'p mut [i32],
}

impl<'p> Slot<'p> {
    /// The slot at `base` of the pool: a heap of `capacity` entries, then
    /// `below` entries for subtract-mean.
    #[inline(always)]
    pub fn at(
        values: &'p mut [i32],
        positions: &'p mut [u16],
        base: usize,
        capacity: usize,
        below: usize,
    ) -> Self {
        let (heap_values, below) = values[base..][..capacity + below].split_at_mut(capacity);
        Slot {
            heap_values,
            heap_positions: &mut positions[base..][..capacity],
            below,
        }
    }
}

/// Selection state of one open window (the pool slot holds the heap).
#[derive(Clone, Copy, Debug)]
pub struct SelectionState {
    /// Heap capacity C; 0 when the window does no selection.
    capacity: u16,
    len: u16,
    below_len: u16,
    tie_count: u16,
    /// The heap minimum, kept here once the heap is full so that rejecting
    /// a segment needs no access to the pool.
    min: i32,
    tie_sum_i: u32,
    tie_sum_j: u32,
    below_max: i32,
    /// Weighted sums, used directly when there is no selection.
    moments: Moments,
}

impl SelectionState {
    pub const EMPTY: SelectionState = SelectionState {
        capacity: 0,
        len: 0,
        below_len: 0,
        tie_count: 0,
        min: NOTHING,
        tie_sum_i: 0,
        tie_sum_j: 0,
        below_max: NOTHING,
        moments: Moments::ZERO,
    };

    pub fn new(capacity: u16) -> Self {
        SelectionState {
            capacity,
            ..Self::EMPTY
        }
    }

    /// Heap capacity C (0: no selection).
    pub fn capacity(&self) -> u16 {
        self.capacity
    }

    /// Whether the heap is full, so that [`push`](Self::push) can reject a
    /// segment whose maximum is below the minimum without the pool.
    #[inline(always)]
    pub fn is_full(&self) -> bool {
        self.len == self.capacity
    }

    /// Whether a full heap rejects every pixel of a segment: all are below
    /// `v(C)` so far (or equal to it for `subtract-next`, whose bucket is
    /// not kept). If so, returns what [`reject`](Self::reject) needs: the
    /// segment's maximum for `subtract-next-distinct`.
    #[inline(always)]
    pub fn rejects<R: Rule>(&self, values: &[i32]) -> Option<i32> {
        if R::RULE == RuleKind::SubtractNextDistinct {
            let max = values.iter().copied().fold(NOTHING, i32::max);
            return (max < self.min).then_some(max);
        }
        // A pixel is accepted iff p > t. |t|, |p| <= 2^25, so t - p cannot
        // overflow, and its sign bit is set exactly for accepted pixels: one
        // subtraction and one OR per pixel, no branch.
        let t = if R::KEEPS_TIES {
            self.min - 1
        } else {
            self.min
        };
        let accepted = values.iter().fold(0, |any, &p| any | (t - p));
        (accepted >= 0).then_some(NOTHING)
    }

    /// A segment that [`rejects`](Self::rejects) returned `Some(max)` for:
    /// only what the rule remembers below `v(N)` changes.
    #[inline(always)]
    pub fn reject<R: Rule>(&mut self, below: &mut [i32], values: &[i32], max: i32) {
        match R::RULE {
            RuleKind::SubtractNextDistinct => self.below_max = self.below_max.max(max),
            RuleKind::SubtractMean => {
                for &p in values {
                    self.drop_below::<R>(below, p);
                }
            }
            _ => {}
        }
    }

    /// Adds the calibrated values of one row segment of the window: columns
    /// `i0 ..` of window row `j`.
    #[inline(always)]
    pub fn push<R: Rule>(&mut self, slot: &mut Slot<'_>, values: &[i32], i0: u16, j: u16) {
        if self.capacity == 0 {
            self.moments.add_row(values, i0, j);
            return;
        }
        let capacity = self.capacity as usize;
        let heap = &mut *slot.heap_values;
        let positions = &mut slot.heap_positions[..heap.len()];
        let mut rest = values;
        let mut i = i0;
        // Fill phase: the first C pixels of the window go straight in.
        if (self.len as usize) < capacity {
            let len = self.len as usize;
            let take = (capacity - len).min(rest.len());
            let (fill, after) = rest.split_at(take);
            for ((h, p), (&v, k)) in heap[len..]
                .iter_mut()
                .zip(&mut positions[len..])
                .zip(fill.iter().zip(0u16..))
            {
                *h = v;
                *p = pack(i + k, j);
            }
            self.len += take as u16;
            i += take as u16;
            rest = after;
            if (self.len as usize) < capacity {
                return;
            }
            heapify(heap, positions);
            self.min = heap[0];
        }
        let mut min = self.min;
        for &p in rest {
            if p > min {
                let evicted_position = positions[0];
                let evicted = min;
                min = replace_min(heap, positions, p, pack(i, j));
                if R::KEEPS_TIES {
                    if min == evicted {
                        self.add_tie(evicted_position);
                    } else {
                        // The minimum rose: the bucket and the evicted pixel
                        // are now strictly below it, for good.
                        self.flush_ties::<R>(slot.below, evicted);
                        self.drop_below::<R>(slot.below, evicted);
                    }
                }
            } else if R::KEEPS_TIES && p == min {
                self.add_tie(pack(i, j));
            } else {
                self.drop_below::<R>(slot.below, p);
            }
            i += 1;
        }
        self.min = min;
    }

    #[inline(always)]
    fn add_tie(&mut self, position: u16) {
        self.tie_count += 1;
        self.tie_sum_i += (position & COLUMN_MASK) as u32;
        self.tie_sum_j += (position >> COLUMN_BITS) as u32;
    }

    fn flush_ties<R: Rule>(&mut self, below: &mut [i32], value: i32) {
        if self.tie_count == 0 {
            return;
        }
        match R::RULE {
            RuleKind::SubtractNextDistinct => self.below_max = self.below_max.max(value),
            RuleKind::SubtractMean => {
                for _ in 0..self.tie_count.min(below.len() as u16) {
                    self.drop_below::<R>(below, value);
                }
            }
            _ => {}
        }
        self.tie_count = 0;
        self.tie_sum_i = 0;
        self.tie_sum_j = 0;
    }

    #[inline(always)]
    fn drop_below<R: Rule>(&mut self, below: &mut [i32], p: i32) {
        match R::RULE {
            RuleKind::SubtractNextDistinct => self.below_max = self.below_max.max(p),
            RuleKind::SubtractMean => {
                let len = self.below_len as usize;
                if len < below.len() {
                    below[len] = p;
                    sift_up(&mut below[..=len]);
                    self.below_len += 1;
                } else if p > below[0] {
                    below[0] = p;
                    sift_down_values(below);
                }
            }
            _ => {}
        }
    }

    /// The window's last pixel has arrived: weights (SPEC.md §3, with the §4
    /// filter if any) reduced to the centre-of-gravity moments.
    pub fn finish<R: Rule>(
        &self,
        slot: &Slot<'_>,
        level_filter: Option<(&mut LevelFilterState, u8)>,
    ) -> Moments {
        if self.capacity == 0 {
            return self.moments;
        }
        let capacity = self.capacity as usize;
        let heap = &slot.heap_values[..capacity];
        let positions = &slot.heap_positions[..capacity];
        let min = heap[0];
        let instantaneous = match R::RULE {
            RuleKind::Threshold => None,
            RuleKind::SubtractNext => Some(min),
            RuleKind::SubtractNextDistinct => (self.below_max != NOTHING).then_some(self.below_max),
            RuleKind::SubtractMean => {
                let below = &slot.below[..self.below_len as usize];
                (!below.is_empty()).then(|| {
                    let sum: i32 = below.iter().sum();
                    sum.div_euclid(below.len() as i32)
                })
            }
        };
        let level = match level_filter {
            Some((state, gain_shift)) => state.update(instantaneous, gain_shift),
            None => instantaneous,
        };
        let weight = |p: i32| match level {
            Some(level) => (p - level).max(0),
            None => p,
        };
        let mut moments = Moments::ZERO;
        for (&p, &position) in heap.iter().zip(positions) {
            if R::RULE == RuleKind::SubtractNext && p == min {
                continue; // p <= v(N+1): not kept
            }
            moments.add(weight(p), position & COLUMN_MASK, position >> COLUMN_BITS);
        }
        if R::KEEPS_TIES && self.tie_count > 0 {
            moments.add_group(weight(min), self.tie_count, self.tie_sum_i, self.tie_sum_j);
        }
        moments
    }
}

fn heapify(values: &mut [i32], positions: &mut [u16]) {
    for start in (0..values.len() / 2).rev() {
        sift_down(values, positions, start, values[start], positions[start]);
    }
}

/// Replaces the minimum of a full heap with `value` (larger than it) and
/// restores the heap; returns the new minimum.
#[inline(always)]
fn replace_min(values: &mut [i32], positions: &mut [u16], value: i32, position: u16) -> i32 {
    sift_down(values, positions, 0, value, position);
    values[0]
}

/// Puts `value` (with `position`) into the hole at `hole` (`< values.len()`)
/// and sifts it down. The smaller child is chosen without a branch; the only
/// data-dependent branch is where `value` stops.
#[inline(always)]
fn sift_down(values: &mut [i32], positions: &mut [u16], hole: usize, value: i32, position: u16) {
    let n = values.len();
    assert!(hole < n && positions.len() >= n);
    // 1-based indices (children of `k` are `2k` and `2k + 1`, one shift)
    // through pointers one entry before the slices (wrapping arithmetic: they
    // point outside them); only indices 1..=n are dereferenced.
    let v = values.as_mut_ptr().wrapping_sub(1);
    let p = positions.as_mut_ptr().wrapping_sub(1);
    // SAFETY: every index `k` dereferenced below is in `1..=n`, i.e. entry
    // `k - 1 < n` of `values` (length n) and of `positions` (at least n):
    // `hole` starts in `1..=n` (asserted) and only takes values of `child`
    // or `left`; `left < n` (so `child <= left + 1 <= n`) and `left <= n`
    // are checked by the conditions that guard their use.
    unsafe {
        let mut hole = hole + 1;
        let mut left = 2 * hole;
        while left < n {
            let (l, r) = (*v.wrapping_add(left), *v.wrapping_add(left + 1));
            // Branch-free: |values| < 2^25, so `r - l` cannot overflow and
            // `right` is all ones exactly when `r < l`.
            let right = (r - l) >> 31;
            let smaller = l + ((r - l) & right);
            let child = left + (right & 1) as usize;
            if smaller >= value {
                break;
            }
            *v.wrapping_add(hole) = smaller;
            *p.wrapping_add(hole) = *p.wrapping_add(child);
            hole = child;
            left = 2 * hole;
        }
        // A last single child (the last entry) when n is even.
        if left == n && *v.wrapping_add(left) < value {
            *v.wrapping_add(hole) = *v.wrapping_add(left);
            *p.wrapping_add(hole) = *p.wrapping_add(left);
            hole = left;
        }
        *v.wrapping_add(hole) = value;
        *p.wrapping_add(hole) = position;
    }
}

fn sift_down_values(values: &mut [i32]) {
    let n = values.len();
    let mut i = 0;
    let value = values[0];
    loop {
        let left = 2 * i + 1;
        if left >= n {
            break;
        }
        let right = left + 1;
        let child = if right < n && values[right] < values[left] {
            right
        } else {
            left
        };
        if values[child] >= value {
            break;
        }
        values[i] = values[child];
        i = child;
    }
    values[i] = value;
}

fn sift_up(values: &mut [i32]) {
    let mut i = values.len() - 1;
    let value = values[i];
    while i > 0 {
        let parent = (i - 1) / 2;
        if values[parent] <= value {
            break;
        }
        values[i] = values[parent];
        i = parent;
    }
    values[i] = value;
}
