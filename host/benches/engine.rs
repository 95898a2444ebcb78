//! `cargo bench -p brightpix --bench engine`: the host half of
//! `brightpix bench` (the library's [`brightpix::bench`]), on the built-in
//! workloads: the engine on all cores and on one, against a per-window sort
//! in the engine's arithmetic, DARC's method (f32 copy, quicksort,
//! next-distinct), an nth_element quickselect and a branch-free quickselect,
//! and the no-selection baseline, all on the same frames in interleaved
//! rounds, each peer checked to agree with the engine first.
//!
//! `BRIGHTPIX_BENCH_PIXELS` (pixels of frames per workload, default
//! 4000000), `BRIGHTPIX_BENCH_ROUNDS` (default 20) and
//! `BRIGHTPIX_BENCH_RUN_MS` (shortest timed run, default 100) change the
//! length; `BRIGHTPIX_BENCH_THREADS` the all-cores thread count.

use brightpix::bench::host::{host_table, peer_table};
use brightpix::bench::{run_host, workloads, HostOptions};

fn env(name: &str) -> Option<usize> {
    std::env::var(name).ok().and_then(|v| v.parse().ok())
}

fn main() {
    let pixels = env("BRIGHTPIX_BENCH_PIXELS").unwrap_or(4_000_000);
    let options = HostOptions {
        rounds: env("BRIGHTPIX_BENCH_ROUNDS").unwrap_or(20),
        threads: env("BRIGHTPIX_BENCH_THREADS"),
        min_run_seconds: env("BRIGHTPIX_BENCH_RUN_MS").unwrap_or(100) as f64 * 1e-3,
    };
    let rows: Vec<_> = workloads::standard(pixels)
        .iter()
        .map(|w| run_host(w, &options).unwrap_or_else(|e| panic!("{e:#}")))
        .collect();
    print!("{}", host_table(&rows));
    println!();
    print!("{}", peer_table(&rows));
}
