//! The streaming engine against the independent reference, bit for bit, on
//! random cameras, windows, rules, calibration maps, pixel distributions and
//! chunkings (SPEC.md is the contract both implement).

use brightpix::engine_runner::HostEngine;
use brightpix::reference::Reference;
use brightpix_tests::case;
use proptest::prelude::*;

/// Cases per run; `PROPTEST_CASES` overrides.
fn cases() -> u32 {
    std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10_000)
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: cases(),
        max_shrink_iters: 2000,
        ..ProptestConfig::default()
    })]

    #[test]
    fn engine_matches_reference((case, frames, chunks) in case()) {
        let config = case.config();
        let mut reference = Reference::new(&config).expect("generated configurations are valid");
        let mut engine = HostEngine::new(config).expect("generated configurations are valid");
        let mut chunk_lengths = chunks.iter().copied().cycle();
        let engine_frames = engine
            .process_chunked(frames.iter().map(Vec::as_slice), &mut chunk_lengths)
            .expect("generated frames are in range");
        prop_assert_eq!(engine_frames.len(), frames.len());
        for (f, (frame, engine_results)) in frames.iter().zip(&engine_frames).enumerate() {
            let expected = reference.process_frame(frame).expect("generated frames are in range");
            prop_assert_eq!(expected.len(), engine_results.len());
            for (want, got) in expected.iter().zip(engine_results) {
                prop_assert_eq!(
                    (want.index, want.slope_x, want.slope_y, want.flux, want.valid),
                    (got.index as usize, got.slope_x, got.slope_y, got.flux, got.valid),
                    "frame {} sub-aperture {} window {:?}", f, want.index, case.windows[want.index]
                );
            }
        }
    }
}
