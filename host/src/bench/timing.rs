//! Timing on a noisy shared machine. Each task first gets a repeat count
//! that makes one of its runs last at least the requested time (a run of a
//! few milliseconds measures the scheduler as much as the code); then every
//! task runs once per round, rounds interleave the tasks (starting each
//! round at the next task, so none always runs first or last), the first
//! round is a warm-up, and each task's figure is the minimum, median and
//! maximum over the timed rounds. Ratios between two tasks are taken round
//! by round (the two runs of a round are seconds apart, so a slow spell of
//! the machine mostly slows both) and summarised the same way.

use serde::Serialize;
use std::time::Instant;

/// Minimum, median and maximum of a set of figures.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Stats {
    pub min: f64,
    pub median: f64,
    pub max: f64,
}

impl Stats {
    /// Of `values` (the median of an even count is the mean of the middle
    /// two); all 0 if there are none.
    pub fn of(values: &[f64]) -> Stats {
        if values.is_empty() {
            return Stats::default();
        }
        let mut sorted = values.to_vec();
        sorted.sort_by(f64::total_cmp);
        let mid = sorted.len() / 2;
        let median = if sorted.len() % 2 == 1 {
            sorted[mid]
        } else {
            (sorted[mid - 1] + sorted[mid]) / 2.0
        };
        Stats {
            min: sorted[0],
            median,
            max: sorted[sorted.len() - 1],
        }
    }

    /// `f` of each figure, for a decreasing `f` (a time into a rate): the
    /// minimum becomes the maximum.
    pub fn map_decreasing(self, f: impl Fn(f64) -> f64) -> Stats {
        Stats {
            min: f(self.max),
            median: f(self.median),
            max: f(self.min),
        }
    }
}

/// A task to time: runs its work the given number of times.
pub type Task<'a> = &'a mut dyn FnMut(usize);

/// What [`interleaved`] measured.
#[derive(Clone, Debug, Default)]
pub struct Timings {
    /// Per task, per timed round: seconds per repetition of its work.
    pub seconds: Vec<Vec<f64>>,
    /// Per task: repetitions of its work in its last run.
    pub repeats: Vec<usize>,
    /// The shortest timed run of any task, seconds.
    pub shortest_run: f64,
}

impl Timings {
    /// Task `k`'s seconds per repetition.
    pub fn stats(&self, k: usize) -> Stats {
        Stats::of(&self.seconds[k])
    }

    /// Task `a`'s time over task `b`'s, round by round.
    pub fn ratio(&self, a: usize, b: usize) -> Stats {
        let ratios: Vec<f64> = self.seconds[a]
            .iter()
            .zip(&self.seconds[b])
            .map(|(a, b)| a / b.max(1e-300))
            .collect();
        Stats::of(&ratios)
    }
}

/// A repeat count for which one run of `task` takes at least `min_seconds`
/// (0 seconds: one repetition), from runs of growing length.
pub fn calibrate(task: Task<'_>, min_seconds: f64) -> usize {
    let mut repeats = 1usize;
    loop {
        let started = Instant::now();
        task(repeats);
        match calibration_step(repeats, started.elapsed().as_secs_f64(), min_seconds) {
            Calibration::Done(repeats) => return repeats,
            Calibration::Try(more) => repeats = more,
        }
    }
}

/// What a calibration run of `repeats` repetitions that took `seconds`
/// says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Calibration {
    /// Runs of this many repetitions take at least the target.
    Done(usize),
    /// The run was too short to scale from: try this many.
    Try(usize),
}

/// A run of at least a quarter of the target gives a time per repetition
/// steady enough to scale from; the count is then scaled to the target with
/// a quarter to spare, so that a run in a quiet spell does not fall short.
/// A shorter run asks for a longer one (at most 100 times longer).
pub fn calibration_step(repeats: usize, seconds: f64, min_seconds: f64) -> Calibration {
    const MAX: usize = 1 << 30;
    if seconds >= min_seconds / 4.0 || repeats >= MAX {
        let per_repeat = (seconds / repeats as f64).max(1e-12);
        let wanted = (1.25 * min_seconds / per_repeat).ceil();
        return Calibration::Done((wanted as usize).clamp(1, MAX));
    }
    let factor = if seconds > 0.0 {
        ((min_seconds / 4.0 / seconds).ceil() as usize).clamp(2, 100)
    } else {
        100
    };
    Calibration::Try(repeats.saturating_mul(factor).min(MAX))
}

/// Calibrates every task to runs of at least `min_seconds`, then runs them
/// for one warm-up round and `rounds` timed interleaved rounds. A run that
/// falls short of `min_seconds` is redone with more repetitions (so every
/// timed run lasts at least `min_seconds`).
pub fn interleaved(rounds: usize, min_seconds: f64, tasks: &mut [Task<'_>]) -> Timings {
    let rounds = rounds.max(1);
    let mut repeats: Vec<usize> = tasks
        .iter_mut()
        .map(|task| calibrate(*task, min_seconds))
        .collect();
    let count = tasks.len();
    let mut seconds = vec![Vec::with_capacity(rounds); count];
    let mut shortest_run = f64::INFINITY;
    for round in 0..=rounds {
        for step in 0..count {
            let k = (round + step) % count;
            // A run in a quiet spell can be shorter than the calibration
            // said: it is redone longer, and so are the task's later runs.
            let run = loop {
                let started = Instant::now();
                (tasks[k])(repeats[k]);
                let run = started.elapsed().as_secs_f64();
                match calibration_step(repeats[k], run, min_seconds) {
                    Calibration::Done(more) if run < min_seconds => {
                        repeats[k] = more.max(repeats[k] + 1)
                    }
                    Calibration::Try(more) => repeats[k] = more,
                    Calibration::Done(_) => break run,
                }
            };
            if round > 0 {
                seconds[k].push(run / repeats[k] as f64);
                shortest_run = shortest_run.min(run);
            }
        }
    }
    Timings {
        seconds,
        repeats,
        shortest_run: if count == 0 { 0.0 } else { shortest_run },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_of_known_values() {
        assert_eq!(
            Stats::of(&[3.0, 1.0, 2.0]),
            Stats {
                min: 1.0,
                median: 2.0,
                max: 3.0
            }
        );
        assert_eq!(
            Stats::of(&[4.0, 1.0, 2.0, 3.0]),
            Stats {
                min: 1.0,
                median: 2.5,
                max: 4.0
            }
        );
        assert_eq!(Stats::of(&[]), Stats::default());
        assert_eq!(
            Stats::of(&[2.0, 4.0, 8.0]).map_decreasing(|t| 8.0 / t),
            Stats {
                min: 1.0,
                median: 2.0,
                max: 4.0
            }
        );
    }

    #[test]
    fn ratios_are_taken_round_by_round() {
        let timings = Timings {
            seconds: vec![vec![2.0, 6.0, 3.0], vec![1.0, 2.0, 3.0]],
            repeats: vec![1, 1],
            shortest_run: 1.0,
        };
        // Per round 2, 3, 1: not the ratio of the medians (3 / 2).
        assert_eq!(
            timings.ratio(0, 1),
            Stats {
                min: 1.0,
                median: 2.0,
                max: 3.0
            }
        );
    }

    #[test]
    fn every_task_runs_once_per_round_plus_the_warm_up() {
        let (mut a, mut b) = (Vec::new(), Vec::new());
        let timings = interleaved(5, 0.0, &mut [&mut |r| a.push(r), &mut |r| b.push(r)]);
        // One calibration run each (a zero target needs one repetition),
        // the warm-up and five rounds.
        assert_eq!((a.len(), b.len()), (7, 7));
        assert!(a.iter().chain(&b).all(|&r| r == 1));
        assert_eq!(
            timings.seconds.iter().map(Vec::len).collect::<Vec<_>>(),
            [5, 5]
        );
        assert_eq!(timings.repeats, [1, 1]);
    }

    #[test]
    fn calibration_scales_the_repeats_to_the_target() {
        // 1/8 s a repetition, a 1 s target: one repetition is too short to
        // scale from (under a quarter of the target), four are enough, and
        // ten (1 s and a quarter) is the count.
        assert_eq!(calibration_step(1, 0.125, 1.0), Calibration::Try(2));
        assert_eq!(calibration_step(4, 0.5, 1.0), Calibration::Done(10));
        assert_eq!(calibration_step(1, 1e-9, 0.1), Calibration::Try(100));
        assert_eq!(calibration_step(1, 0.0, 0.0), Calibration::Done(1));
    }
}
