//! Pixels from the simulated DCMI ring (`camera_sim`), cut into runs by the
//! firmware's camera source and pushed through the engine as they come,
//! give the results of a direct run of the engine on the camera's frames.

mod camera_sim;

use brightpix::engine_runner::EngineBuffers;
use brightpix_firmware::camera::{DataWidth, DcmiSource};
use brightpix_firmware::device::PixelSource;
use brightpix_firmware::engine::{Engine, OutputSink, SubapertureResult};
use brightpix_protocol::{
    Calibration, Camera, Centroid, Config, LevelFilter, PixelCount, RegularGrid, Selection,
    SelectionRule, SubapertureWindow,
};
use brightpix_tests::direct;
use camera_sim::*;

const WIDTHS: [DataWidth; 4] = [
    DataWidth::Bits8,
    DataWidth::Bits10,
    DataWidth::Bits12,
    DataWidth::Bits14,
];

fn windows() -> Vec<SubapertureWindow> {
    RegularGrid {
        x: 2,
        y: 1,
        columns: 5,
        rows: 4,
        width: 8,
        height: 7,
        pitch_x: 8,
        pitch_y: 7,
    }
    .windows()
    .collect()
}

fn config<'a>(
    camera: Camera,
    windows: &'a [SubapertureWindow],
    level_filter: Option<LevelFilter>,
) -> Config<'a> {
    Config {
        camera,
        windows,
        calibration: Calibration {
            background: None,
            gain: None,
            threshold: None,
        },
        selection: Selection {
            rule: SelectionRule::SubtractMean { count: 3 },
            count: PixelCount::All(6),
            level_filter,
        },
        centroid: Centroid {
            reference_slopes: None,
            min_flux: 0,
        },
        crop: None,
    }
}

/// Spots on noise, within `bits`.
fn frames(camera: Camera, count: u32, seed: u64) -> Vec<Vec<u16>> {
    let mut rng = Rng::new(seed);
    let max = camera.max_raw() as u64;
    let (w, h) = (camera.width as usize, camera.height as usize);
    (0..count)
        .map(|_| {
            let mut f: Vec<u16> = (0..w * h)
                .map(|_| (rng.next() % (max / 8 + 1)) as u16)
                .collect();
            for _ in 0..(w * h / 30) {
                let (x, y) = (rng.range(0, w - 1), rng.range(0, h - 1));
                let peak = max / 2 + rng.next() % (max / 2);
                for (dx, dy, div) in [(0, 0, 1), (1, 0, 3), (0, 1, 3), (1, 1, 5)] {
                    if x + dx < w && y + dy < h {
                        let p = &mut f[(y + dy) * w + x + dx];
                        *p = (*p as u64).max(peak / div) as u16;
                    }
                }
            }
            f
        })
        .collect()
}

struct Sink<'a> {
    out: &'a mut Vec<SubapertureResult>,
    done: bool,
}

impl OutputSink for Sink<'_> {
    fn subaperture(&mut self, result: SubapertureResult) {
        self.out.push(result);
    }
    fn frame_complete(&mut self, _frame: u32) {
        self.done = true;
    }
}

/// The engine fed the runs as the device loop feeds them: a run that
/// continues the frame is pushed; one at pixel 0 starts a frame (a frame in
/// progress is aborted); a gap aborts the frame and skips the rest of it.
/// Returns the completed frames' numbers and results.
fn through_engine(config: Config<'_>, runs: &[Run]) -> Vec<(u32, Vec<SubapertureResult>)> {
    let mut buffers = EngineBuffers::for_config(&config);
    let mut engine = Engine::new(config, buffers.memory()).unwrap();
    let mut current: Option<(u32, u32, Vec<SubapertureResult>)> = None;
    let mut completed = Vec::new();
    for run in runs {
        match &current {
            Some((f, next, _)) if *f == run.frame && *next == run.first_pixel => {}
            _ if run.first_pixel == 0 => {
                if current.is_some() {
                    engine.abort_frame();
                }
                current = Some((run.frame, 0, Vec::new()));
            }
            _ => {
                // A gap (or the rest of a frame after one).
                if current.take().is_some() {
                    engine.abort_frame();
                }
                continue;
            }
        }
        let (f, next, out) = current.as_mut().unwrap();
        let mut sink = Sink { out, done: false };
        engine.push(&run.pixels, &mut sink).unwrap();
        *next += run.pixels.len() as u32;
        if sink.done {
            let (f, _, out) = (*f, 0, std::mem::take(out));
            completed.push((f, out));
            current = None;
        }
    }
    completed
}

fn by_index(mut results: Vec<SubapertureResult>) -> Vec<SubapertureResult> {
    // Windows that end in the same row may be emitted in another order
    // when the row arrives in other pieces.
    results.sort_by_key(|r| r.index);
    results
}

#[allow(clippy::too_many_arguments)] // a test scenario, spelled out at each call
fn capture(
    data: DataWidth,
    camera: Camera,
    frames: &[Vec<u16>],
    ring: usize,
    behaviour: Behaviour,
    seed: u64,
    max_chunk: usize,
    stall: impl FnMut(u64) -> usize,
) -> Vec<Run> {
    let sim = SimRing::new(ring, behaviour, seed);
    let (mut words, mut pixels) = (vec![0u32; 48], vec![0u16; 4 * 48]);
    let mut source = DcmiSource::new(sim.clone(), data, &mut words, &mut pixels);
    source.start(camera, None).unwrap();
    for f in frames {
        sim.send_frame(data, f);
    }
    let mut rng = Rng::new(seed + 1);
    drive(
        &mut source,
        &sim,
        &mut rng,
        |r| r.range(1, max_chunk),
        stall,
    )
}

#[test]
fn camera_runs_through_the_engine_equal_a_direct_run() {
    let windows = windows();
    for (k, data) in WIDTHS.into_iter().enumerate() {
        let camera = Camera {
            width: 44,
            height: 30,
            bit_depth: data.bits(),
        };
        // The level filter carries state from frame to frame: every frame
        // must be there, in order.
        let config = config(camera, &windows, Some(LevelFilter { gain_shift: 2 }));
        config.validate().unwrap();
        let frames = frames(camera, 12, 40 + k as u64);
        let expected = direct(config, &frames);
        let behaviour = Behaviour {
            late_events: true,
            speculate_percent: 10,
            start_events: u32::MAX - 5,
            ..Behaviour::default()
        };
        // A ring of 64 words: about a tenth of a frame.
        let runs = capture(data, camera, &frames, 64, behaviour, k as u64, 12, |_| 0);
        let got = through_engine(config, &runs);
        assert_eq!(got.len(), frames.len(), "{data:?}: every frame completes");
        for (f, (frame, results)) in got.into_iter().enumerate() {
            assert_eq!(frame, f as u32);
            assert_eq!(
                by_index(results),
                by_index(expected[f].clone()),
                "{data:?} frame {f}"
            );
        }
    }
}

#[test]
fn frames_completed_despite_overruns_and_bad_frames_equal_a_direct_run() {
    let windows = windows();
    for (k, data) in WIDTHS.into_iter().enumerate() {
        let camera = Camera {
            width: 44,
            height: 30,
            bit_depth: data.bits(),
        };
        // No level filter: each frame's results stand alone.
        let config = config(camera, &windows, None);
        let frames = frames(camera, 30, 90 + k as u64);
        let expected = direct(config, &frames);
        let mut stall_rng = Rng::new(k as u64);
        let runs = capture(
            data,
            camera,
            &frames,
            128,
            Behaviour {
                late_events: true,
                race_words: 3,
                speculate_percent: 10,
                ..Behaviour::default()
            },
            k as u64,
            40,
            |_| {
                if stall_rng.chance(3) {
                    stall_rng.range(50, 600)
                } else {
                    0
                }
            },
        );
        let got = through_engine(config, &runs);
        assert!(!got.is_empty() && got.len() < frames.len(), "{}", got.len());
        for (frame, results) in got {
            assert_eq!(
                by_index(results),
                by_index(expected[frame as usize].clone()),
                "{data:?} frame {frame}"
            );
        }
    }
}
