//! Simulation in the loop: simulated Shack-Hartmann frames streamed to a
//! device and its slopes checked bit for bit against the reference. Used by
//! `brightpix demo`, `brightpix stream --verify` and the tests.

use std::path::Path;
use std::time::Duration;

use brightpix_protocol::{Camera, Config};

use crate::config_file::ProcessingConfig;
use crate::link::verify::Verifier;
use crate::link::{Client, FrameOutcome, LinkError, StreamReport};
use crate::simulator::{SimulationParams, Simulator};

/// The paper's CANARY model (`examples/canary.toml`, built in): 112x112
/// 16-bit camera, 7x7 sub-apertures of 16x16, subtract-next N = 20,
/// 50-count background.
pub fn canary_config() -> ProcessingConfig {
    ProcessingConfig::from_toml_str(
        include_str!("../../examples/canary.toml"),
        Path::new("examples/canary.toml"),
    )
    .expect("examples/canary.toml is valid")
}

/// `count` frames of `camera`, each tiled with `columns x rows` independent
/// simulator spots (`sim.size()` pixels square) from the top-left corner;
/// pixels outside the tiles are the simulator's background. Frame `k` uses
/// spots `k * columns * rows ..` of run `seed`.
pub fn tiled_frames(
    sim: &Simulator,
    camera: Camera,
    columns: usize,
    rows: usize,
    count: usize,
    seed: u64,
) -> Vec<Vec<u16>> {
    let size = sim.size();
    let (width, height) = (camera.width as usize, camera.height as usize);
    assert!(
        columns * size <= width && rows * size <= height,
        "tiles outside the camera"
    );
    let per_frame = columns * rows;
    let spots = sim.frames(seed, 0, per_frame * count);
    let background = sim.calibration_background().round() as u16;
    spots
        .chunks(per_frame)
        .map(|tiles| {
            let mut frame = vec![background; width * height];
            for (t, spot) in tiles.iter().enumerate() {
                let (x0, y0) = ((t % columns) * size, (t / columns) * size);
                for y in 0..size {
                    let row = (y0 + y) * width + x0;
                    frame[row..row + size].copy_from_slice(&spot.raw[y * size..(y + 1) * size]);
                }
            }
            frame
        })
        .collect()
}

/// `count` CANARY frames (49 spots of the paper's default NGS each).
pub fn canary_frames(count: usize, seed: u64) -> Vec<Vec<u16>> {
    let sim = Simulator::new(SimulationParams::canary()).expect("the paper's parameters are valid");
    tiled_frames(&sim, canary_config().camera, 7, 7, count, seed)
}

/// The result of [`stream_and_verify`].
pub struct VerifiedStream {
    pub report: StreamReport,
    pub verifier: Verifier,
    /// Outcomes in the order received.
    pub outcomes: Vec<FrameOutcome>,
    /// The link error that ended the stream early, if any.
    pub error: Option<LinkError>,
}

impl VerifiedStream {
    /// Frames per second of the stream itself (verification excluded).
    pub fn frames_per_second(&self) -> f64 {
        self.report.frames_done as f64 / self.report.elapsed.as_secs_f64().max(1e-9)
    }

    /// Mean time per frame.
    pub fn per_frame(&self) -> Duration {
        self.report
            .elapsed
            .checked_div(self.report.frames_done.max(1) as u32)
            .unwrap_or_default()
    }
}

/// Streams `frames` (numbered from `first_frame`) to a device configured
/// with `config`, then checks every result against the reference, which
/// sees the same frames in the same order (so the device's level filters
/// must have been reset with the configuration, as an upload does). The
/// first `keep` mismatches are kept. On a link error, the outcomes received
/// are verified all the same and the error is in [`VerifiedStream::error`].
pub fn stream_and_verify(
    client: &mut Client,
    config: &Config<'_>,
    frames: &[Vec<u16>],
    first_frame: u32,
    keep: usize,
) -> VerifiedStream {
    let mut verifier = Verifier::new(config, keep).expect("the configuration was accepted");
    let mut outcomes = Vec::with_capacity(frames.len());
    let result = client.stream_frames(first_frame, frames, |o| outcomes.push(o));
    verify_outcomes(&mut verifier, frames, first_frame, &outcomes);
    let (report, error) = match result {
        Ok(report) => (report, None),
        Err(e) => (StreamReport::default(), Some(e)),
    };
    VerifiedStream {
        report,
        verifier,
        outcomes,
        error,
    }
}

/// Checks outcomes (in any order) against `frames` numbered from
/// `first_frame`, feeding the reference in frame order.
pub fn verify_outcomes(
    verifier: &mut Verifier,
    frames: &[Vec<u16>],
    first_frame: u32,
    outcomes: &[FrameOutcome],
) {
    let mut by_frame: Vec<Option<&FrameOutcome>> = vec![None; frames.len()];
    for o in outcomes {
        let k = o.frame().wrapping_sub(first_frame) as usize;
        if let Some(slot) = by_frame.get_mut(k) {
            *slot = Some(o);
        }
    }
    for (pixels, outcome) in frames.iter().zip(by_frame) {
        if let Some(o) = outcome {
            verifier.check(pixels, o);
        }
    }
}
