//! The bench's peers compute what the engine computes (their times mean
//! nothing otherwise): the per-window sort in the engine's arithmetic
//! exactly, on random configurations (every rule, maps, per-sub-aperture N,
//! the level filter over several frames); DARC's method and the two
//! quickselects within 2^-16 pixel of the engine's subtract-next-distinct on
//! spot frames, for any N; the no-selection baseline exactly equal to the
//! engine with N at least every window's pixel count, on random
//! configurations (maps, threshold, reference slopes, minimum flux, any
//! window shapes).

use brightpix::bench::baseline::NoSelectionPeer;
use brightpix::bench::peers::{FloatPeer, Peer, PeerSlope, Selector, SortPeer};
use brightpix::engine_runner::HostEngine;
use brightpix_protocol::SelectionRule;
use brightpix_tests::{case, PixelCounts};
use proptest::prelude::*;

fn cases() -> u32 {
    brightpix_tests::cases_or(10_000) / 20
}

proptest! {
    #![proptest_config(brightpix_tests::differential_config(cases()))]

    #[test]
    fn the_sort_peer_is_the_engine((case, frames, _chunks) in case()) {
        let config = case.view();
        let mut engine = HostEngine::new(config).unwrap();
        let want = engine.process(frames.iter().map(Vec::as_slice), usize::MAX).unwrap();
        let mut peer = SortPeer::new(&config);
        let mut slopes = vec![PeerSlope::default(); config.windows.len()];
        for (frame, want) in frames.iter().zip(&want) {
            peer.process(frame, &mut slopes);
            prop_assert_eq!(&peer.results, want);
        }
    }

    #[test]
    fn the_no_selection_baseline_is_the_engine_with_no_selection(
        (mut case, frames, _chunks) in case(),
        beyond in 0u16..3,
    ) {
        let largest = case.windows.iter().map(|w| w.pixel_count()).max().unwrap() as u16;
        case.pixels = PixelCounts::All(largest + beyond);
        let config = case.view();
        let mut engine = HostEngine::new(config).unwrap();
        let want = engine.process(frames.iter().map(Vec::as_slice), usize::MAX).unwrap();
        let mut peer = NoSelectionPeer::new(&config);
        let mut slopes = vec![PeerSlope::default(); config.windows.len()];
        for (frame, want) in frames.iter().zip(&want) {
            peer.process(frame, &mut slopes);
            prop_assert_eq!(&peer.results, want);
        }
    }

    #[test]
    fn float_peers_are_within_2_to_the_minus_16_of_the_engine(
        n in prop_oneof![1u16..=30, 200u16..=300],
        per_subaperture in prop::option::of(prop::collection::vec(1u16..=255, 49)),
        seed in 0u64..1000,
    ) {
        let mut config = brightpix::sil::canary_config();
        config.rule = SelectionRule::SubtractNextDistinct;
        config.pixels = match per_subaperture {
            Some(list) => PixelCounts::PerSubaperture(list),
            None => PixelCounts::All(n),
        };
        let pixels = brightpix::bench::workloads::spot_frames(&config, 2, seed);
        let frames: Vec<Vec<u16>> = pixels.chunks(112 * 112).map(<[u16]>::to_vec).collect();
        let view = config.view();
        let want = HostEngine::new(view).unwrap().process(frames.iter().map(Vec::as_slice), usize::MAX).unwrap();
        for selector in [Selector::Sort, Selector::NthElement, Selector::BranchFree] {
            let mut peer = FloatPeer::new(&view, selector);
            let mut slopes = vec![PeerSlope::default(); 49];
            for (frame, want) in frames.iter().zip(&want) {
                peer.process(frame, &mut slopes);
                for (got, want) in slopes.iter().zip(want) {
                    prop_assert_eq!(got.valid, want.valid);
                    let dx = (got.x - want.slope_x as f64 / 65536.0).abs();
                    let dy = (got.y - want.slope_y as f64 / 65536.0).abs();
                    prop_assert!(dx.max(dy) <= 1.0 / 65536.0, "{:?}: {:?} against {:?}", selector, got, want);
                }
            }
        }
    }
}
