//! The baselines the engine is compared with (the host benchmark's, in
//! `host/benches/engine.rs`, without the heap).

use brightpix_firmware::engine::centroid::{Centroider, Moments};
use brightpix_firmware::engine::SubapertureResult;

use crate::frames::{CANARY_ACROSS, CANARY_WIDTH, SIDE};

pub const CANARY_WINDOWS: usize = CANARY_ACROSS * CANARY_ACROSS;

/// The memory floor: every pixel read once.
#[inline(never)]
pub fn sum_pixels(frame: &[u16]) -> u32 {
    frame.iter().map(|&p| p as u32).sum()
}

/// The floor for any selection: centre of gravity of the pixels above a
/// known threshold, straight from the frame, no selection.
#[inline(never)]
pub fn threshold_cog(frame: &[u16], threshold: i32, out: &mut [(i64, i64, i64); CANARY_WINDOWS]) {
    for sy in 0..CANARY_ACROSS {
        for sx in 0..CANARY_ACROSS {
            let (mut f, mut fx, mut fy) = (0i64, 0i64, 0i64);
            for j in 0..SIDE {
                let row = &frame[(sy * SIDE + j) * CANARY_WIDTH + sx * SIDE..][..SIDE];
                for (i, &p) in row.iter().enumerate() {
                    let w = (p as i32 - threshold).max(0) as i64;
                    f += w;
                    fx += w * i as i64;
                    fy += w * j as i64;
                }
            }
            out[sy * CANARY_ACROSS + sx] = (f, fx, fy);
        }
    }
}

/// The paper's and DARC's selection in the engine's arithmetic (SPEC.md §2,
/// §3 subtract-next, §5) for one 16x16 window: calibrate into `i32`, sort a
/// copy (`sort_unstable`), subtract `v(N+1)`, centre of gravity. `pixels`
/// (and `background`, if any, laid out the same) start at the window's top
/// row, `stride` pixels per row; the window starts at column `x`.
#[inline(never)]
pub fn sort_window(
    pixels: &[u16],
    background: Option<&[i32]>,
    stride: usize,
    x: usize,
    n: usize,
    centroider: &Centroider<'_>,
    index: u16,
) -> SubapertureResult {
    const PIXELS: usize = SIDE * SIDE;
    let mut values = [0i32; PIXELS];
    let mut sorted = [0i32; PIXELS];
    for j in 0..SIDE {
        let at = j * stride + x;
        let raw = &pixels[at..at + SIDE];
        let row = &mut values[j * SIDE..][..SIDE];
        match background {
            Some(b) => {
                for ((v, &r), &b) in row.iter_mut().zip(raw).zip(&b[at..at + SIDE]) {
                    *v = ((r as i32) << 4) - b;
                }
            }
            None => {
                for (v, &r) in row.iter_mut().zip(raw) {
                    *v = (r as i32) << 4;
                }
            }
        }
    }
    sorted.copy_from_slice(&values);
    sorted.sort_unstable();
    let level = sorted[PIXELS - 1 - n];
    let mut moments = Moments::ZERO;
    for (k, &p) in values.iter().enumerate() {
        moments.add((p - level).max(0), (k % SIDE) as u16, (k / SIDE) as u16);
    }
    centroider.result(index, moments, SIDE as u16, SIDE as u16)
}
