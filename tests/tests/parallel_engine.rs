//! The engine on all cores (`brightpix::parallel`) against the same engine on
//! one ([`HostEngine`], frame after frame) and against the independent
//! reference, bit for bit: random cameras, windows (overlapping, vignetted
//! grids), rules, maps, per-sub-aperture N, the level filter carried across
//! batches, thread counts that split frames or bands of sub-apertures.

use brightpix::engine_runner::HostEngine;
use brightpix::io::FrameShape;
use brightpix::parallel::{BatchError, BatchResults, ParallelEngine};
use brightpix::reference::Reference;
use brightpix_firmware::engine::{FrameError, SubapertureResult};
use brightpix_protocol::LevelFilter;
use brightpix_tests::{case, PixelCounts};
use proptest::prelude::*;

/// Cases per run; `PROPTEST_CASES` overrides.
fn cases() -> u32 {
    brightpix_tests::cases_or(10_000) / 20
}

fn shape(camera: brightpix_protocol::Camera, frames: usize) -> FrameShape {
    FrameShape {
        frames,
        height: camera.height as usize,
        width: camera.width as usize,
    }
}

/// `HostEngine`'s results for `frames`, in sub-aperture order.
fn sequential(engine: &mut HostEngine<'_>, frames: &[Vec<u16>]) -> Vec<Vec<SubapertureResult>> {
    engine
        .process(frames.iter().map(Vec::as_slice), usize::MAX)
        .expect("frames are in range")
}

fn assert_batch_eq(
    got: &BatchResults,
    want: &[Vec<SubapertureResult>],
    context: &str,
) -> Result<(), TestCaseError> {
    prop_assert_eq!(got.frames, want.len());
    for (f, frame) in want.iter().enumerate() {
        let got: Vec<_> = got.frame(f).collect();
        prop_assert_eq!(&got, frame, "frame {} of the batch ({})", f, context);
    }
    Ok(())
}

proptest! {
    #![proptest_config(brightpix_tests::differential_config(cases()))]

    /// Frames repeated to make batches of up to 12, cut into two batches at a
    /// random frame, on 1 to 4 threads: the parallel engine gives exactly
    /// what one engine gives frame after frame, and what the reference gives.
    #[test]
    fn parallel_matches_sequential_and_reference(
        (case, frames, _chunks) in case(),
        repeat in 1usize..=4,
        threads in 1usize..=4,
        cut in any::<prop::sample::Index>(),
    ) {
        let frames: Vec<Vec<u16>> = frames.iter().cycle().take(frames.len() * repeat).cloned().collect();
        let config = case.view();
        let mut one = HostEngine::new(config).unwrap();
        let mut reference = Reference::new(&config).unwrap();
        let mut all = ParallelEngine::new(&config, Some(threads)).unwrap();
        let cut = cut.index(frames.len() + 1);
        for batch in [&frames[..cut], &frames[cut..]] {
            let want = sequential(&mut one, batch);
            for (frame, engine) in batch.iter().zip(&want) {
                let expected: Vec<_> = reference.process_frame(frame).unwrap().into_iter().map(|o| SubapertureResult {
                    index: o.index as u16,
                    slope_x: o.slope_x,
                    slope_y: o.slope_y,
                    flux: o.flux,
                    valid: o.valid,
                }).collect();
                prop_assert_eq!(&expected, engine, "engine against reference");
            }
            let pixels = batch.concat();
            let got = all.process(&pixels, shape(case.camera, batch.len())).unwrap();
            assert_batch_eq(&got, &want, &format!("{threads} threads, {} bands", all.bands()))?;
        }
    }
}

/// A CANARY-sized case on every path: level filter with per-sub-aperture N
/// (band path, bands cutting a row of sub-apertures), without it (frame
/// path), a batch of one frame (band path without the filter), and a reset.
#[test]
fn canary_with_level_filter_and_per_subaperture_n() {
    let mut config = brightpix::sil::canary_config();
    config.level_filter = Some(LevelFilter { gain_shift: 2 });
    config.pixels = PixelCounts::PerSubaperture((0..49).map(|k| 5 + (k * 7) % 40).collect());
    let frames = brightpix::sil::canary_frames(24, 7);
    let camera = config.camera;
    for filtered in [true, false] {
        let mut config = config.clone();
        if !filtered {
            config.level_filter = None;
        }
        let view = config.view();
        for threads in [2, 3] {
            let mut one = HostEngine::new(view).unwrap();
            let mut all = ParallelEngine::new(&view, Some(threads)).unwrap();
            assert_eq!(all.bands(), threads);
            for batch in [&frames[..1], &frames[1..10], &frames[10..]] {
                let want = sequential(&mut one, batch);
                let got = all
                    .process(&batch.concat(), shape(camera, batch.len()))
                    .unwrap();
                for (f, frame) in want.iter().enumerate() {
                    assert_eq!(&got.frame(f).collect::<Vec<_>>(), frame);
                }
            }
            // After a reset both start again from the instantaneous level.
            all.reset_level_filters();
            let mut fresh = HostEngine::new(view).unwrap();
            let want = sequential(&mut fresh, &frames[..5]);
            let got = all
                .process(&frames[..5].concat(), shape(camera, 5))
                .unwrap();
            for (f, frame) in want.iter().enumerate() {
                assert_eq!(&got.frame(f).collect::<Vec<_>>(), frame);
            }
        }
    }
}

/// A batch with an out-of-range pixel is refused whole: the error names the
/// frame, row and column, and the level-filter state is as if the batch had
/// never been given.
#[test]
fn a_bad_pixel_refuses_the_batch_and_keeps_the_state() {
    let mut config = brightpix::sil::canary_config();
    config.camera.bit_depth = 12;
    config.level_filter = Some(LevelFilter { gain_shift: 3 });
    let view = config.view();
    let frames = brightpix::sil::canary_frames(6, 3);
    for threads in [1, 2] {
        let mut one = HostEngine::new(view).unwrap();
        let mut all = ParallelEngine::new(&view, Some(threads)).unwrap();
        let first = all
            .process(&frames[..3].concat(), shape(view.camera, 3))
            .unwrap();
        let want = sequential(&mut one, &frames[..3]);
        assert_eq!(first.frame(2).collect::<Vec<_>>(), want[2]);
        let mut bad = frames[3..].concat();
        let frame_pixels = 112 * 112;
        bad[frame_pixels + 40 * 112 + 17] = 4096;
        assert_eq!(
            all.process(&bad, shape(view.camera, 3)),
            Err(BatchError::Pixel {
                frame: 1,
                error: FrameError::PixelOutOfRange {
                    row: 40,
                    column: 17,
                    value: 4096
                }
            })
        );
        let got = all
            .process(&frames[3..].concat(), shape(view.camera, 3))
            .unwrap();
        let want = sequential(&mut one, &frames[3..]);
        for (f, frame) in want.iter().enumerate() {
            assert_eq!(&got.frame(f).collect::<Vec<_>>(), frame);
        }
    }
}
