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

/// Simulated Shack-Hartmann frames and the slopes that made them.
#[derive(Clone, Debug, PartialEq)]
pub struct TiledSimulation {
    /// The camera frames, row-major.
    pub frames: Vec<Vec<u16>>,
    /// Per frame, per tile (row by row): the noiseless spot's centre of
    /// gravity in pixels from the tile's centre, `[x, y]`
    /// ([`SpotFrame::true_slope`](crate::simulator::SpotFrame::true_slope)).
    pub true_slopes: Vec<Vec<[f64; 2]>>,
    /// Per frame, per tile: the wavefront's G-tilt as a spot displacement
    /// in pixels ([`SpotFrame::phase_slope`](crate::simulator::SpotFrame::phase_slope)).
    pub phase_slopes: Vec<Vec<[f64; 2]>>,
}

/// `count` frames of `camera`, each tiled with `columns x rows` independent
/// simulator spots (`sim.size()` pixels square) from the top-left corner;
/// pixels outside the tiles are the simulator's background. Frame `k` uses
/// spots `k * columns * rows ..` of run `seed`. Panics if the tiles do not
/// fit the camera.
pub fn simulate_tiled(
    sim: &Simulator,
    camera: Camera,
    columns: usize,
    rows: usize,
    count: usize,
    seed: u64,
) -> TiledSimulation {
    let size = sim.size();
    let (width, height) = (camera.width as usize, camera.height as usize);
    assert!(
        columns * size <= width && rows * size <= height,
        "tiles outside the camera"
    );
    let per_frame = columns * rows;
    let spots = sim.frames(seed, 0, per_frame * count);
    let background = sim.calibration_background().round() as u16;
    let mut out = TiledSimulation {
        frames: Vec::with_capacity(count),
        true_slopes: Vec::with_capacity(count),
        phase_slopes: Vec::with_capacity(count),
    };
    for tiles in spots.chunks(per_frame) {
        let mut frame = vec![background; width * height];
        for (t, spot) in tiles.iter().enumerate() {
            let (x0, y0) = ((t % columns) * size, (t / columns) * size);
            for y in 0..size {
                let row = (y0 + y) * width + x0;
                frame[row..row + size].copy_from_slice(&spot.raw[y * size..(y + 1) * size]);
            }
        }
        out.frames.push(frame);
        out.true_slopes
            .push(tiles.iter().map(|s| s.true_slope).collect());
        out.phase_slopes
            .push(tiles.iter().map(|s| s.phase_slope).collect());
    }
    out
}

/// The frames of [`simulate_tiled`].
pub fn tiled_frames(
    sim: &Simulator,
    camera: Camera,
    columns: usize,
    rows: usize,
    count: usize,
    seed: u64,
) -> Vec<Vec<u16>> {
    simulate_tiled(sim, camera, columns, rows, count, seed).frames
}

/// Simulation conditions by name: `"ngs"` (the paper's CANARY NGS, also
/// `"canary"`), `"rayleigh:DEPTH[:ALTITUDE]"` (the paper's Rayleigh LGS,
/// range-gate depth and gate altitude in metres, 20 km by default) or
/// `"sodium:SEPARATION[:ALTITUDE]"` (the paper's sodium LGS, peak
/// separation and lower peak altitude in metres, 90 km by default).
pub fn named_conditions(name: &str) -> Result<SimulationParams, String> {
    use crate::evaluation::tune::Lgs;
    use crate::simulator::Source;
    let expected = "expected \"ngs\", \"rayleigh:DEPTH[:ALTITUDE]\" or \"sodium:SEPARATION[:ALTITUDE]\" (metres)";
    if name == "ngs" || name == "canary" {
        return Ok(SimulationParams::canary());
    }
    let lgs = Lgs::parse(name).map_err(|_| format!("conditions {name:?}: {expected}"))?;
    Ok(match lgs {
        Lgs::Rayleigh {
            gate_depth_m,
            altitude_m,
        } => {
            let mut p = SimulationParams::canary_rayleigh(gate_depth_m);
            if let Source::Rayleigh { altitude_m: a, .. } = &mut p.source {
                *a = altitude_m;
            }
            p
        }
        Lgs::Sodium {
            separation_m,
            altitude_m,
        } => {
            let mut p = SimulationParams::sodium(separation_m);
            if let Source::Sodium {
                lower_peak_altitude_m: a,
                ..
            } = &mut p.source
            {
                *a = altitude_m;
            }
            p
        }
    })
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
    stream_and_verify_with(client, config, frames, first_frame, keep, || {})
}

/// [`stream_and_verify`], calling `on_outcome` as each frame's outcome
/// arrives (a progress bar, for instance).
pub fn stream_and_verify_with(
    client: &mut Client,
    config: &Config<'_>,
    frames: &[Vec<u16>],
    first_frame: u32,
    keep: usize,
    mut on_outcome: impl FnMut(),
) -> VerifiedStream {
    let mut verifier = Verifier::new(config, keep).expect("the configuration was accepted");
    let mut outcomes = Vec::with_capacity(frames.len());
    let result = client.stream_frames(first_frame, frames, |o| {
        outcomes.push(o);
        on_outcome();
    });
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
/// `first_frame`, feeding the reference in frame order. A frame without an
/// outcome is a failure ([`Verifier::missing`]); outcomes of other frames
/// are ignored.
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
        match outcome {
            Some(o) => {
                verifier.check(pixels, o);
            }
            None => verifier.missing(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiled_simulation_places_each_spot_and_its_slopes() {
        let mut params = SimulationParams::canary();
        params.pixels_per_subaperture = 8;
        let sim = Simulator::new(params).unwrap();
        let camera = Camera {
            width: 20,
            height: 9,
            bit_depth: 16,
        };
        let run = simulate_tiled(&sim, camera, 2, 1, 3, 5);
        assert_eq!(run.frames.len(), 3);
        assert_eq!(run.true_slopes.len(), 3);
        let spots = sim.frames(5, 0, 6);
        for (k, frame) in run.frames.iter().enumerate() {
            assert_eq!(frame.len(), 20 * 9);
            for t in 0..2 {
                let spot = &spots[2 * k + t];
                assert_eq!(run.true_slopes[k][t], spot.true_slope);
                assert_eq!(run.phase_slopes[k][t], spot.phase_slope);
                for y in 0..8 {
                    let row = &frame[y * 20 + 8 * t..y * 20 + 8 * t + 8];
                    assert_eq!(row, &spot.raw[y * 8..y * 8 + 8]);
                }
            }
            // outside the tiles: the background
            assert!(frame[16..20].iter().all(|&p| p == 50));
            assert!(frame[8 * 20..].iter().all(|&p| p == 50));
        }
        assert_eq!(tiled_frames(&sim, camera, 2, 1, 3, 5), run.frames);
    }

    #[test]
    fn conditions_by_name() {
        use crate::simulator::Source;
        assert_eq!(named_conditions("ngs").unwrap(), SimulationParams::canary());
        assert_eq!(
            named_conditions("rayleigh:1000").unwrap(),
            SimulationParams::canary_rayleigh(1000.0)
        );
        let p = named_conditions("sodium:5000:85000").unwrap();
        assert_eq!(p.pixel_scale_arcsec, 1.5);
        assert!(matches!(
            p.source,
            Source::Sodium { separation_m, lower_peak_altitude_m, .. }
                if separation_m == 5000.0 && lower_peak_altitude_m == 85000.0
        ));
        let err = named_conditions("lgs").unwrap_err();
        assert!(
            err.starts_with("conditions \"lgs\": expected \"ngs\""),
            "{err}"
        );
    }
}
