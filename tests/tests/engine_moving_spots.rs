//! The streaming engine against the reference on frames built to reach the
//! engine's rarer paths: a spot per window that jumps, brightens and dims
//! from frame to frame over a noisy floor, so that the seed carried from
//! the last frame is often wrong and a window's `v(N+1)` falls below its
//! hint (the last row's windows then lower their hint to the cutoff so far
//! before they are prepared). Uniform random frames (`engine_vs_reference`)
//! rarely do that. The other rules on the same frames: their closed-form
//! ends (`stream::closed_form`) take `v(N)` from above the hint, at the
//! hint or (the ordinary end) below it, and their level from the front,
//! the hint's copies, the back or the low ties, as the spot moves.

use brightpix_protocol::{Camera, SelectionRule, SubapertureWindow};
use brightpix_tests::{Case, PixelCounts};
use proptest::prelude::*;

fn cases() -> u32 {
    brightpix_tests::cases_or(2_000)
}

/// One frame: noise in `0..=noise` everywhere, and in each window a spot
/// (a peak of `peak` falling off by half a step a pixel) at `(cx, cy)`.
fn frame(camera: Camera, side: u16, noise: &[u16], spots: &[(u16, u16, u16)]) -> Vec<u16> {
    let max = camera.max_raw();
    let across = camera.width / side;
    let mut out = noise.to_vec();
    for (k, &(cx, cy, peak)) in spots.iter().enumerate() {
        let (x0, y0) = ((k as u16 % across) * side, (k as u16 / across) * side);
        for j in 0..side {
            for i in 0..side {
                let d = i.abs_diff(cx) + j.abs_diff(cy);
                let p = (peak >> d.min(15)) as u32;
                let at = (y0 + j) as usize * camera.width as usize + (x0 + i) as usize;
                out[at] = (out[at] as u32 + p).min(max as u32) as u16;
            }
        }
    }
    out
}

fn moving_spots(
    rule: impl Strategy<Value = SelectionRule>,
) -> impl Strategy<Value = (Case, Vec<Vec<u16>>, Vec<usize>)> {
    (
        rule,
        4u16..=12,
        2u16..=4,
        2u16..=4,
        3usize..=6,
        1u16..=40,
        0u16..=40,
    )
        .prop_flat_map(|(rule, side, across, down, frame_count, n, noise)| {
            let camera = Camera {
                width: side * across,
                height: side * down,
                bit_depth: 12,
            };
            let windows = (across * down) as usize;
            let spot = (0..side, 0..side, 0u16..=4095);
            (
                Just((camera, side, n, rule)),
                prop::collection::vec(
                    (
                        prop::collection::vec(0..=noise, camera.pixel_count()),
                        prop::collection::vec(spot, windows),
                    ),
                    frame_count,
                ),
                // Whole rows, or runs across rows.
                prop_oneof![
                    Just(vec![camera.width as usize]),
                    prop::collection::vec(1usize..=3 * camera.width as usize, 1..4),
                ],
            )
        })
        .prop_map(|((camera, side, n, rule), frames, chunks)| {
            let across = camera.width / side;
            let windows = (0..(camera.width / side) * (camera.height / side))
                .map(|k| SubapertureWindow {
                    x: (k % across) * side,
                    y: (k / across) * side,
                    width: side,
                    height: side,
                })
                .collect();
            let case = Case {
                camera,
                windows,
                grid: None,
                background: None,
                gain: None,
                threshold: None,
                rule,
                pixels: PixelCounts::All(n.min(side * side - 1)),
                level_filter: None,
                reference_slopes: None,
                min_flux: 0,
                crop: None,
            };
            let frames = frames
                .iter()
                .map(|(noise, spots)| frame(camera, side, noise, spots))
                .collect();
            (case, frames, chunks)
        })
}

proptest! {
    #![proptest_config(brightpix_tests::differential_config(cases()))]

    #[test]
    fn engine_matches_reference_on_moving_spots(
        (case, frames, chunks) in moving_spots(Just(SelectionRule::SubtractNext))
    ) {
        brightpix_tests::engine_matches_reference(&case, &frames, &chunks)?;
    }

    #[test]
    fn the_other_rules_match_reference_on_moving_spots(
        (case, frames, chunks) in moving_spots(prop_oneof![
            Just(SelectionRule::Threshold),
            Just(SelectionRule::SubtractNextDistinct),
            (1u16..=16).prop_map(|count| SelectionRule::SubtractMean { count }),
        ])
    ) {
        brightpix_tests::engine_matches_reference(&case, &frames, &chunks)?;
    }
}
