//! `cargo bench -p brightpix --bench engine`: the streaming engine against
//! the reference (full sort per sub-aperture, as DARC and the paper) and
//! against the floor for any selection, a centre of gravity with a known
//! threshold, at the paper's defaults (CANARY: 7x7 sub-apertures of 16x16
//! pixels, subtract-next, N = 20, 200 photons, 50 counts of background).
//!
//! A second baseline is the paper's and DARC's method in the engine's own
//! arithmetic: calibrate a sub-aperture into `i32`, fully sort it
//! (`sort_unstable`), take `v(N+1)`, then the centre of gravity of
//! `max(0, p - v(N+1))`; its results are checked equal to the engine's, so
//! the engine's speed-up over sorting is measured on the same work.
//!
//! Reports ns/pixel and ratios to the threshold-CoG baseline measured in the
//! same run (the machines are noisy: only the ratios mean much). Set
//! `BRIGHTPIX_BENCH_FRAMES` to change the number of frames.

use brightpix::engine_runner::HostEngine;
use brightpix::reference::Reference;
use brightpix_firmware::engine::centroid::{Centroider, Moments};
use brightpix_firmware::engine::SubapertureResult;
use brightpix_protocol::{
    Calibration, Camera, Centroid, Config, PixelCount, RegularGrid, Selection, SelectionRule,
};
use std::hint::black_box;
use std::time::Instant;

const SIDE: u16 = 16;
const ACROSS: u16 = 7;

/// Deterministic Shack-Hartmann-like frames: a Gaussian spot per
/// sub-aperture at a random offset, 200 photons, 50 counts of background,
/// uniform noise of +-3 counts (a bench needs realistic pixel statistics, not
/// physics: see `brightpix paper` for those).
fn frames(count: usize) -> Vec<Vec<u16>> {
    let width = (SIDE * ACROSS) as usize;
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..count)
        .map(|_| {
            let mut frame = vec![0u16; width * width];
            for sy in 0..ACROSS as usize {
                for sx in 0..ACROSS as usize {
                    let cx = 7.5 + (next() - 0.5) * 6.0;
                    let cy = 7.5 + (next() - 0.5) * 6.0;
                    for j in 0..SIDE as usize {
                        for i in 0..SIDE as usize {
                            let r2 = (i as f64 - cx).powi(2) + (j as f64 - cy).powi(2);
                            let spot =
                                200.0 / (2.0 * std::f64::consts::PI * 2.25) * (-r2 / 4.5).exp();
                            let v = 50.0 + spot + (next() - 0.5) * 6.0;
                            frame[(sy * 16 + j) * width + sx * 16 + i] = v.round() as u16;
                        }
                    }
                }
            }
            frame
        })
        .collect()
}

/// The floor: centre of gravity of pixels above a known threshold, straight
/// from a frame in memory, no selection.
fn threshold_cog(frame: &[u16], width: usize, threshold: i32, out: &mut Vec<(i64, i64, i64)>) {
    out.clear();
    for sy in 0..ACROSS as usize {
        for sx in 0..ACROSS as usize {
            let (mut f, mut fx, mut fy) = (0i64, 0i64, 0i64);
            for j in 0..SIDE as usize {
                let row = &frame[(sy * 16 + j) * width + sx * 16..][..SIDE as usize];
                for (i, &p) in row.iter().enumerate() {
                    let w = (p as i32 - threshold).max(0) as i64;
                    f += w;
                    fx += w * i as i64;
                    fy += w * j as i64;
                }
            }
            out.push((f, fx, fy));
        }
    }
}

/// The paper's and DARC's selection in the engine's arithmetic (SPEC.md §2,
/// §3 subtract-next, §5): per sub-aperture, calibrate into `i32`, sort a copy
/// (`sort_unstable`), subtract `v(N+1)`, centre of gravity.
fn sort_subtract_next(
    frame: &[u16],
    width: usize,
    background: &[i32],
    n: usize,
    centroider: &Centroider<'_>,
    out: &mut Vec<SubapertureResult>,
) {
    const PIXELS: usize = (SIDE * SIDE) as usize;
    let side = SIDE as usize;
    let mut values = [0i32; PIXELS];
    let mut sorted = [0i32; PIXELS];
    out.clear();
    for sy in 0..ACROSS as usize {
        for sx in 0..ACROSS as usize {
            for j in 0..side {
                let at = (sy * side + j) * width + sx * side;
                let raw = &frame[at..at + side];
                let background = &background[at..at + side];
                for ((v, &r), &b) in values[j * side..][..side]
                    .iter_mut()
                    .zip(raw)
                    .zip(background)
                {
                    *v = ((r as i32) << 4) - b;
                }
            }
            sorted.copy_from_slice(&values);
            sorted.sort_unstable();
            let level = sorted[PIXELS - 1 - n];
            let mut moments = Moments::ZERO;
            for (k, &p) in values.iter().enumerate() {
                moments.add((p - level).max(0), (k % side) as u16, (k / side) as u16);
            }
            let index = (sy * ACROSS as usize + sx) as u16;
            out.push(centroider.result(index, moments, SIDE, SIDE));
        }
    }
}

fn time<F: FnMut()>(mut f: F, repeats: usize) -> f64 {
    f(); // warm up
    let mut best = f64::MAX;
    for _ in 0..repeats {
        let start = Instant::now();
        f();
        best = best.min(start.elapsed().as_secs_f64());
    }
    best
}

fn main() {
    let count: usize = std::env::var("BRIGHTPIX_BENCH_FRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(200);
    let frames = frames(count);
    let width = (SIDE * ACROSS) as usize;
    let pixels = (count * width * width) as f64;
    let grid = RegularGrid {
        x: 0,
        y: 0,
        columns: ACROSS,
        rows: ACROSS,
        width: SIDE,
        height: SIDE,
        pitch_x: SIDE,
        pitch_y: SIDE,
    };
    let windows: Vec<_> = grid.windows().collect();
    let background = vec![50 * 16; width * width];
    let config_with = |rule, n| Config {
        camera: Camera {
            width: width as u16,
            height: width as u16,
            bit_depth: 16,
        },
        windows: &windows,
        calibration: Calibration {
            background: Some(&background),
            ..Calibration::default()
        },
        selection: Selection {
            rule,
            count: PixelCount::All(n),
            level_filter: None,
        },
        centroid: Centroid::default(),
    };
    let paper = config_with(SelectionRule::SubtractNext, 20);

    let mut cog = Vec::new();
    let floor = time(
        || {
            for f in &frames {
                threshold_cog(black_box(f), width, 50, &mut cog);
                black_box(&cog);
            }
        },
        5,
    );
    let mut results = vec![("threshold CoG (floor)", floor)];
    let mut no_selection = HostEngine::new(config_with(SelectionRule::Threshold, 256)).unwrap();
    results.push((
        "engine, no selection (N >= 256)",
        time(
            || {
                black_box(
                    no_selection
                        .process(frames.iter().map(Vec::as_slice), usize::MAX)
                        .unwrap(),
                );
            },
            5,
        ),
    ));
    for (name, rule) in [
        ("engine, subtract-next N=20", SelectionRule::SubtractNext),
        ("engine, threshold N=20", SelectionRule::Threshold),
        (
            "engine, subtract-next-distinct N=20",
            SelectionRule::SubtractNextDistinct,
        ),
        (
            "engine, subtract-mean M=4 N=20",
            SelectionRule::SubtractMean { count: 4 },
        ),
    ] {
        let mut engine = HostEngine::new(config_with(rule, 20)).unwrap();
        results.push((
            name,
            time(
                || {
                    black_box(
                        engine
                            .process(frames.iter().map(Vec::as_slice), usize::MAX)
                            .unwrap(),
                    );
                },
                5,
            ),
        ));
    }
    let centroider = Centroider::new(paper.centroid);
    let mut sorted = Vec::new();
    let engine_results = HostEngine::new(paper)
        .unwrap()
        .process(frames.iter().map(Vec::as_slice), usize::MAX)
        .unwrap();
    for (frame, expected) in frames.iter().zip(&engine_results) {
        sort_subtract_next(frame, width, &background, 20, &centroider, &mut sorted);
        assert_eq!(
            &sorted, expected,
            "the sorting baseline must match the engine"
        );
    }
    results.push((
        "sort per sub-aperture (i32, sort_unstable), subtract-next N=20",
        time(
            || {
                for f in &frames {
                    sort_subtract_next(
                        black_box(f),
                        width,
                        &background,
                        20,
                        &centroider,
                        &mut sorted,
                    );
                    black_box(&sorted);
                }
            },
            5,
        ),
    ));
    let mut engine = HostEngine::new(paper).unwrap();
    results.push((
        "engine, subtract-next N=20, 64-pixel chunks",
        time(
            || {
                black_box(
                    engine
                        .process(frames.iter().map(Vec::as_slice), 64)
                        .unwrap(),
                );
            },
            5,
        ),
    ));
    let mut reference = Reference::new(&paper).unwrap();
    results.push((
        "reference (full sort, i128), subtract-next N=20",
        time(
            || {
                for f in &frames {
                    black_box(reference.process_frame(f).unwrap());
                }
            },
            2,
        ),
    ));
    println!(
        "brightpix engine benchmark: {count} frames of {width}x{width}, 7x7 sub-apertures of 16x16"
    );
    println!("{:<64} {:>10} {:>12}", "variant", "ns/pixel", "x floor");
    for (name, seconds) in results {
        println!(
            "{:<64} {:>10.2} {:>12.2}",
            name,
            seconds * 1e9 / pixels,
            seconds / floor
        );
    }
}
