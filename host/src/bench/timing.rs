//! Timing on a noisy shared machine: every method runs once per round,
//! rounds interleave the methods (starting each round at the next method, so
//! none always runs first or last), the first round is a warm-up, and each
//! method's figure is its median round.

use std::time::Instant;

/// Runs `tasks` for `rounds` interleaved rounds after one warm-up round;
/// returns each task's median time in seconds.
pub fn interleaved_medians(rounds: usize, tasks: &mut [&mut dyn FnMut()]) -> Vec<f64> {
    let count = tasks.len();
    let mut times = vec![Vec::with_capacity(rounds); count];
    for round in 0..=rounds.max(1) {
        for step in 0..count {
            let k = (round + step) % count;
            let started = Instant::now();
            (tasks[k])();
            let seconds = started.elapsed().as_secs_f64();
            if round > 0 {
                times[k].push(seconds);
            }
        }
    }
    times.into_iter().map(median).collect()
}

/// The median (mean of the middle two for an even count); 0 if empty.
pub fn median(mut values: Vec<f64>) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    values.sort_by(f64::total_cmp);
    let mid = values.len() / 2;
    if values.len() % 2 == 1 {
        values[mid]
    } else {
        (values[mid - 1] + values[mid]) / 2.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_task_runs_once_per_round_plus_the_warm_up() {
        let (mut a, mut b) = (0, 0);
        let medians = interleaved_medians(5, &mut [&mut || a += 1, &mut || b += 1]);
        assert_eq!((a, b), (6, 6));
        assert_eq!(medians.len(), 2);
        assert_eq!(median(vec![3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(vec![4.0, 1.0, 2.0, 3.0]), 2.5);
    }
}
