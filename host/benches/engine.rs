//! `cargo bench -p brightpix --bench engine`: the host half of
//! `brightpix bench` (the library's [`brightpix::bench`]), on the built-in
//! workloads: the engine on all cores and on one, against a per-window sort
//! in the engine's arithmetic, DARC's method (f32 copy, quicksort,
//! next-distinct), an nth_element quickselect and a branch-free quickselect,
//! all on the same frames in interleaved rounds, each peer checked to agree
//! with the engine first.
//!
//! `BRIGHTPIX_BENCH_PIXELS` (pixels of frames per workload and per timed run,
//! default 4000000) and `BRIGHTPIX_BENCH_ROUNDS` (default 7) change the
//! length; `BRIGHTPIX_BENCH_THREADS` the all-cores thread count.

use brightpix::bench::host::{host_table, peer_table};
use brightpix::bench::{run_host, workloads, HostOptions};

fn env(name: &str) -> Option<usize> {
    std::env::var(name).ok().and_then(|v| v.parse().ok())
}

fn main() {
    let pixels = env("BRIGHTPIX_BENCH_PIXELS").unwrap_or(4_000_000);
    let options = HostOptions {
        rounds: env("BRIGHTPIX_BENCH_ROUNDS").unwrap_or(7),
        threads: env("BRIGHTPIX_BENCH_THREADS"),
        pixels_per_run: pixels,
    };
    let rows: Vec<_> = workloads::standard(pixels)
        .iter()
        .map(|w| run_host(w, &options).unwrap_or_else(|e| panic!("{e:#}")))
        .collect();
    print!("{}", host_table(&rows));
    println!();
    print!("{}", peer_table(&rows));
}
