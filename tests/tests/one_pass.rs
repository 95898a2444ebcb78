//! `select`'s one-pass order statistics in both forms (skipping, for
//! Cortex-M; counting, for hosts) against each other and against their
//! definitions, on values drawn from a few levels (ties, as in a faint
//! spot's window) and from the calibrated range's edges:
//! `two_lowest_above` (the distinct values above the floor, sorted, with
//! their copies) and `largest_and_next` (the largest with its copies'
//! count and coordinate sums, and the largest below it).

use brightpix_firmware::engine::select::{
    largest_and_next, largest_and_next_counting, largest_and_next_skipping, pack, two_lowest_above,
    two_lowest_above_counting, two_lowest_above_skipping, Entry, LargestAndNext, Ties, TwoLowest,
};
use proptest::prelude::*;

/// The largest calibrated magnitude is below 2^25 (SPEC.md §2).
const EDGE: i32 = (1 << 25) - 1;

fn definition(values: &[i32], floor: i32) -> TwoLowest {
    let mut above: Vec<i32> = values.iter().copied().filter(|&p| p > floor).collect();
    above.sort_unstable();
    above.dedup();
    let copies = |v: i32| values.iter().filter(|&&p| p == v).count();
    let (lowest, second) = (
        above.first().copied().unwrap_or(i32::MAX),
        above.get(1).copied().unwrap_or(i32::MAX),
    );
    TwoLowest {
        lowest,
        lowest_copies: if lowest == i32::MAX {
            0
        } else {
            copies(lowest)
        },
        second,
        second_copies: if second == i32::MAX {
            0
        } else {
            copies(second)
        },
    }
}

/// Position `k`: column `k % 64`, row `k / 64 % 64` (a window is at most
/// 64 x 64).
fn entries(values: &[i32]) -> Vec<Entry> {
    values
        .iter()
        .enumerate()
        .map(|(k, &value)| Entry {
            value,
            position: pack(k as u16 % 64, k as u16 / 64 % 64) as u32,
        })
        .collect()
}

fn largest_definition(values: &[i32]) -> LargestAndNext {
    let largest = values.iter().copied().max().unwrap_or(i32::MIN);
    let next = values
        .iter()
        .copied()
        .filter(|&p| p < largest)
        .max()
        .unwrap_or(i32::MIN);
    let mut copies = Ties::NONE;
    for (k, &p) in values.iter().enumerate() {
        if p == largest {
            copies.count += 1;
            copies.sum_i += k as u32 % 64;
            copies.sum_j += k as u32 / 64 % 64;
        }
    }
    LargestAndNext {
        largest,
        copies,
        next,
    }
}

fn check(values: &[i32], floor: i32) {
    let want = definition(values, floor);
    let e = entries(values);
    assert_eq!(
        two_lowest_above_skipping(&e, floor),
        want,
        "{values:?} floor {floor}"
    );
    assert_eq!(
        two_lowest_above_counting(&e, floor),
        want,
        "{values:?} floor {floor}"
    );
    assert_eq!(
        two_lowest_above(&e, floor),
        want,
        "{values:?} floor {floor}"
    );
    let want = largest_definition(values);
    assert_eq!(largest_and_next_skipping(&e), want, "{values:?}");
    assert_eq!(largest_and_next_counting(&e), want, "{values:?}");
    assert_eq!(largest_and_next(&e), want, "{values:?}");
}

#[test]
fn edges_of_the_calibrated_range() {
    check(&[], 0);
    check(&[-EDGE], -EDGE);
    check(&[-EDGE, -EDGE], i32::MIN);
    check(&[EDGE, EDGE, -EDGE, EDGE - 1], -EDGE);
    check(&[EDGE, EDGE - 1, EDGE - 1, EDGE], EDGE - 2);
    check(&[5, 5, 5], 5);
    // A new lowest after the second's copies, a value between after that.
    check(&[40, 40, 30, 40, 35, 30, 35, 20, 10], 10);
    // A new largest after copies of the old one, positions past a row.
    let mut rows: Vec<i32> = (0..150).map(|k| k % 3).collect();
    rows[140] = 7;
    rows[149] = 7;
    check(&rows, 0);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4_000))]

    /// Values on a few levels 16 apart (whole counts), the floor among
    /// them: the ties a level rule's front holds.
    #[test]
    fn levels(levels in prop::collection::vec(0..6i32, 0..=200), floor in -1..6i32) {
        let values: Vec<i32> = levels.iter().map(|l| 16 * l - 7).collect();
        check(&values, 16 * floor - 7);
    }

    /// Any calibrated values and floor.
    #[test]
    fn spread(values in prop::collection::vec(-EDGE..=EDGE, 0..=80), floor in any::<i32>()) {
        check(&values, floor);
    }
}
