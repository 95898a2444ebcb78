//! The streaming engine against the independent reference, bit for bit, on
//! random cameras, windows, rules, calibration maps, pixel distributions and
//! chunkings (SPEC.md is the contract both implement).

use brightpix::reference::Reference;
use brightpix_tests::case;
use proptest::prelude::*;

/// Cases per run; `PROPTEST_CASES` overrides.
fn cases() -> u32 {
    brightpix_tests::cases_or(10_000)
}

proptest! {
    #![proptest_config(brightpix_tests::differential_config(cases()))]

    #[test]
    fn engine_matches_reference((case, frames, chunks) in case()) {
        brightpix_tests::engine_matches_reference(&case, &frames, &chunks)?;
    }
}

/// Pushes of one length running from frame to frame (the frames one after
/// the other in one stream, cut every `chunk` pixels whatever the frame
/// boundaries), as a camera's fixed-size DMA blocks would: each frame meets
/// the pushes at another offset, so where the last row's windows are
/// prepared moves from frame to frame (`Engine::set_prepare_row`, worked
/// out again after each frame whose length the pushes do not divide).
mod pushes_across_frames {
    use super::*;
    use brightpix::engine_runner::EngineBuffers;
    use brightpix_firmware::engine::{Engine, SubapertureResult};

    proptest! {
        #![proptest_config(brightpix_tests::differential_config(cases() / 5))]

        #[test]
        fn engine_matches_reference_with_pushes_across_frames(
            (case, frames, chunks) in case(),
            rows in 1usize..6,
        ) {
            let config = case.view();
            let mut reference = Reference::new(&config).unwrap();
            let mut buffers = EngineBuffers::for_config(&config);
            let mut engine = Engine::new(config, buffers.memory()).unwrap();
            // A length of a few rows and some pixels, so that pushes span
            // rows (the preparation is then several rows early) and meet
            // each frame elsewhere.
            let chunk = rows * case.camera.width as usize + chunks[0];
            let stream = frames.concat();
            let mut got: Vec<SubapertureResult> = Vec::new();
            for piece in stream.chunks(chunk) {
                engine.push(piece, &mut |r: SubapertureResult| got.push(r)).unwrap();
            }
            let windows = config.windows.len();
            prop_assert_eq!(got.len(), frames.len() * windows);
            for (f, (frame, results)) in frames.iter().zip(got.chunks_mut(windows)).enumerate() {
                results.sort_by_key(|r| r.index);
                let want = reference.process_frame(frame).unwrap();
                for (w, g) in want.iter().zip(results.iter()) {
                    prop_assert_eq!(
                        (w.index, w.slope_x, w.slope_y, w.flux, w.valid),
                        (g.index as usize, g.slope_x, g.slope_y, g.flux, g.valid),
                        "frame {} of {}, pushes of {}", f, frames.len(), chunk
                    );
                }
            }
        }
    }
}

/// SPEC.md §8: a frame with an out-of-range pixel. The engine emits exactly
/// the sub-apertures completed before the bad pixel, with the values the
/// reference gives them, and the level-filter state afterwards agrees (the
/// next good frame matches).
mod invalid_pixel {
    use super::*;
    use brightpix::engine_runner::EngineBuffers;
    use brightpix_firmware::engine::{Engine, FrameError, SubapertureResult};

    proptest! {
        #![proptest_config(brightpix_tests::differential_config(cases() / 5))]

        #[test]
        fn engine_stops_at_an_out_of_range_pixel_like_the_reference(
            (case, frames, chunks) in case().prop_filter("needs headroom above max", |(c, _, _)| c.camera.bit_depth < 16),
            bad_at in any::<prop::sample::Index>(),
        ) {
            let config = case.view();
            let mut reference = Reference::new(&config).unwrap();
            let mut buffers = EngineBuffers::for_config(&config);
            let mut engine = Engine::new(config, buffers.memory()).unwrap();
            let mut chunk_lengths = chunks.iter().copied().cycle();

            // Frame 0 is good, frame 1 has a bad pixel, frame 2 is good: the
            // level filter state must come through the bad frame identically.
            let good = &frames[0];
            let pixel = bad_at.index(good.len());
            let mut bad = frames[frames.len() - 1].clone();
            bad[pixel] = case.camera.max_raw() + 1;
            let width = case.camera.width as usize;
            let (row, column) = ((pixel / width) as u16, (pixel % width) as u16);

            let run = |engine: &mut Engine<'_, '_>, frame: &[u16], chunks: &mut dyn Iterator<Item = usize>| {
                let mut emitted: Vec<SubapertureResult> = Vec::new();
                let mut rest = frame;
                let mut outcome = Ok(());
                while !rest.is_empty() {
                    let take = chunks.next().unwrap().clamp(1, rest.len());
                    if let Err(e) = engine.push(&rest[..take], &mut |r: SubapertureResult| emitted.push(r)) {
                        outcome = Err(e);
                        break;
                    }
                    rest = &rest[take..];
                }
                emitted.sort_by_key(|r| r.index);
                (emitted, outcome)
            };
            let compare = |want: &[brightpix::reference::SubapertureOutput], got: &[SubapertureResult]| {
                want.iter().map(|o| (o.index, o.slope_x, o.slope_y, o.flux, o.valid)).collect::<Vec<_>>()
                    == got.iter().map(|r| (r.index as usize, r.slope_x, r.slope_y, r.flux, r.valid)).collect::<Vec<_>>()
            };

            let (emitted, outcome) = run(&mut engine, good, &mut chunk_lengths);
            prop_assert!(outcome.is_ok());
            prop_assert!(compare(&reference.process_frame(good).unwrap(), &emitted));

            // What the reference says about the completed sub-apertures of the bad frame.
            let completed = reference.completed_before(row, column);
            let mut repaired = bad.clone();
            repaired[pixel] = 0;
            let expected: Vec<_> = reference
                .clone()
                .process_frame(&repaired)
                .unwrap()
                .into_iter()
                .filter(|o| completed.contains(&o.index))
                .collect();
            prop_assert!(reference.process_frame(&bad).is_err());
            let (emitted, outcome) = run(&mut engine, &bad, &mut chunk_lengths);
            prop_assert_eq!(
                outcome,
                Err(FrameError::PixelOutOfRange { row, column, value: case.camera.max_raw() + 1 })
            );
            prop_assert!(compare(&expected, &emitted), "completed before the bad pixel");
            prop_assert!(engine.at_frame_start());

            let (emitted, outcome) = run(&mut engine, good, &mut chunk_lengths);
            prop_assert!(outcome.is_ok());
            prop_assert!(compare(&reference.process_frame(good).unwrap(), &emitted), "frame after the bad one");
        }
    }
}
