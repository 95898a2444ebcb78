//! Order statistics at a tier's edge in one pass, where a level rule's
//! window usually ends (see `stream::closed_form`): the two lowest values
//! above a floor, each with its copies (the front's values just above the
//! hint are mostly copies of one or two values, where `v(N)` lies), and the
//! largest value with its copies and the next below it (the back tier's,
//! when `v(N)` fell below the hint).
//!
//! Two forms of each, chosen by the core that runs them: an in-order
//! Cortex-M pays for every instruction and little for a branch, so the
//! *skipping* forms pass over a value that changes nothing in as few
//! instructions as they can; an out-of-order host pays more for a
//! mispredicted branch than for a few instructions, and the skipping
//! forms' branches follow the values, so the *counting* forms count copies
//! without a branch and branch only on a value new to the answer, rare
//! once the answer is near. CANARY subtract-next-distinct on one x86-64
//! core, the counting forms against the skipping: the engine 8% more
//! instructions (`callgrind`) and 1.08x as fast (median of twelve
//! interleaved pairs, 1.06-1.11; `perf`: the two lowest 12% of the time
//! before, 7% after; the back's largest 5%, 3%); on Cortex-M4 the counting
//! two lowest cost 0.19 instructions a pixel (subtract-mean 0.42). Four
//! values a step with SSE2 (copies counted in the lanes, a step with a new
//! value taken value by value) ran no faster than the counting form: its
//! step's branch mispredicts where the counting form's did. The tests
//! compare the forms with each other and with their definitions
//! (`tests/tests/one_pass.rs`).

use super::{column, row, Entry, Ties};

/// The two lowest distinct values above a floor and their copies; a value
/// not found is `i32::MAX` with no copies.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TwoLowest {
    pub lowest: i32,
    pub lowest_copies: usize,
    pub second: i32,
    pub second_copies: usize,
}

impl TwoLowest {
    const NONE: TwoLowest = TwoLowest {
        lowest: i32::MAX,
        lowest_copies: 0,
        second: i32::MAX,
        second_copies: 0,
    };

    /// The counting form's step: copies counted without a branch (a value
    /// not found is `i32::MAX`, which no value equals), a branch only for
    /// a value above `floor` new to the two and below the second. A value
    /// once above the second stays above it (the second only falls), so a
    /// value taken here was never counted.
    #[inline(always)]
    fn count(&mut self, p: i32, floor: i32) {
        self.lowest_copies += (p == self.lowest) as usize;
        self.second_copies += (p == self.second) as usize;
        if p > floor && p < self.second && p != self.lowest {
            self.take(p);
        }
    }

    /// `p`, above the floor and new to the two, below the second.
    #[inline(always)]
    fn take(&mut self, p: i32) {
        if p < self.lowest {
            (self.second, self.second_copies) = (self.lowest, self.lowest_copies);
            (self.lowest, self.lowest_copies) = (p, 1);
        } else {
            (self.second, self.second_copies) = (p, 1);
        }
    }
}

/// The two lowest distinct values of `entries` above `floor`, with their
/// copies: [`two_lowest_above_skipping`] on Cortex-M,
/// [`two_lowest_above_counting`] elsewhere. Every value is below
/// `i32::MAX` (as every calibrated value is, SPEC.md §2).
#[inline(always)]
pub fn two_lowest_above(entries: &[Entry], floor: i32) -> TwoLowest {
    if cfg!(target_arch = "arm") {
        two_lowest_above_skipping(entries, floor)
    } else {
        two_lowest_above_counting(entries, floor)
    }
}

/// [`two_lowest_above`] with a branch per value: one above the second
/// lowest so far (most of them) costs a load, two comparisons and the
/// loop's own.
#[inline(always)]
pub fn two_lowest_above_skipping(entries: &[Entry], floor: i32) -> TwoLowest {
    let mut two = TwoLowest::NONE;
    for e in entries {
        let p = e.value;
        if p <= floor || p > two.second {
            continue;
        }
        if p == two.second {
            two.second_copies += 1;
        } else if p == two.lowest {
            two.lowest_copies += 1;
        } else {
            two.take(p);
        }
    }
    two
}

/// [`two_lowest_above`] with copies counted without a branch and a branch
/// only for a value new to the two (`TwoLowest::count`).
#[inline(always)]
pub fn two_lowest_above_counting(entries: &[Entry], floor: i32) -> TwoLowest {
    let mut two = TwoLowest::NONE;
    for e in entries {
        two.count(e.value, floor);
    }
    two
}

/// The largest value, its copies (count and coordinate sums) and the
/// largest value below it; `i32::MIN` for a value not found (and no
/// copies). Every value is above `i32::MIN` (as every calibrated value is).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LargestAndNext {
    pub largest: i32,
    pub copies: Ties,
    pub next: i32,
}

impl LargestAndNext {
    const NONE: LargestAndNext = LargestAndNext {
        largest: i32::MIN,
        copies: Ties::NONE,
        next: i32::MIN,
    };

    /// `p`, at `position`, above the largest so far.
    #[inline(always)]
    fn take(&mut self, p: i32, position: u16) {
        self.next = self.largest;
        self.largest = p;
        self.copies = Ties::NONE;
        self.copies.add(position);
    }
}

/// [`LargestAndNext`] of `entries`: [`largest_and_next_skipping`] on
/// Cortex-M, [`largest_and_next_counting`] elsewhere.
#[inline(always)]
pub fn largest_and_next(entries: &[Entry]) -> LargestAndNext {
    if cfg!(target_arch = "arm") {
        largest_and_next_skipping(entries)
    } else {
        largest_and_next_counting(entries)
    }
}

/// [`largest_and_next`] with a branch per value.
#[inline(always)]
pub fn largest_and_next_skipping(entries: &[Entry]) -> LargestAndNext {
    let mut top = LargestAndNext::NONE;
    for e in entries {
        if e.value > top.largest {
            top.take(e.value, e.position as u16);
        } else if e.value == top.largest {
            top.copies.add(e.position as u16);
        } else if e.value > top.next {
            top.next = e.value;
        }
    }
    top
}

/// [`largest_and_next`] with copies added without a branch (times 0 or 1)
/// and a branch only for a value above the largest so far.
#[inline(always)]
pub fn largest_and_next_counting(entries: &[Entry]) -> LargestAndNext {
    let mut top = LargestAndNext::NONE;
    for e in entries {
        let (p, position) = (e.value, e.position as u16);
        let copy = (p == top.largest) as u16;
        top.copies.count += copy;
        top.copies.sum_i += (column(position) * copy) as u32;
        top.copies.sum_j += (row(position) * copy) as u32;
        top.next = top.next.max(if p < top.largest { p } else { i32::MIN });
        if p > top.largest {
            top.take(p, position);
        }
    }
    top
}
