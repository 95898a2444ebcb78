//! `cargo bench -p brightpix --bench simulator`: time to simulate one
//! Shack-Hartmann spot, on one core and with rayon, for the paper's NGS,
//! Rayleigh and sodium cases. Reported, not asserted: the machines are noisy.

use brightpix::simulator::{SimulationParams, Simulator};
use std::hint::black_box;
use std::time::Instant;

fn main() {
    for (name, params) in [
        ("ngs", SimulationParams::default()),
        ("rayleigh 1500 m", SimulationParams::canary_rayleigh(1500.0)),
        ("sodium 14 km", SimulationParams::sodium(14e3)),
    ] {
        let sim = Simulator::new(params).unwrap();
        let mut workspace = sim.workspace();
        let n = 500;
        let start = Instant::now();
        for i in 0..n {
            black_box(sim.frame_into(&mut workspace, i, 1, [0.0, 0.0]));
        }
        let one = start.elapsed().as_secs_f64() / n as f64;
        let start = Instant::now();
        black_box(sim.frames(1, 0, 4 * n as usize));
        let parallel = start.elapsed().as_secs_f64() / (4 * n) as f64;
        println!(
            "{name}: {:.3} ms/spot on one core, {:.3} ms/spot with rayon ({} threads)",
            one * 1e3,
            parallel * 1e3,
            rayon::current_num_threads()
        );
    }
}
