//! The paper's and DARC's method in the engine's arithmetic, the peer a
//! user would otherwise run: per sub-aperture, calibrate into `i32`, sort a
//! copy (`sort_unstable`), subtract `v(N+1)`, centre of gravity. It needs a
//! whole window before it can start, so it runs on each row of windows once
//! its last camera row is in.

use brightpix_firmware::engine::centroid::{Centroider, Moments};
use brightpix_firmware::engine::SubapertureResult;

use crate::frames::Grid;

/// The windows of grid row `gy` of `frame`, subtract-next with `n`.
#[inline(never)]
pub fn sort_grid_row(
    frame: &[u16],
    background: Option<&[i32]>,
    grid: Grid,
    gy: usize,
    n: usize,
    centroider: &Centroider<'_>,
    out: &mut [SubapertureResult],
) {
    const MAX: usize = 32 * 32;
    let (side, width) = (grid.side, grid.width());
    let pixels = side * side;
    let mut values = [0i32; MAX];
    let mut sorted = [0i32; MAX];
    for sx in 0..grid.across {
        for j in 0..side {
            let at = (gy * side + j) * width + sx * side;
            for (i, v) in values[j * side..][..side].iter_mut().enumerate() {
                let b = background.map_or(0, |b| b[at + i]);
                *v = ((frame[at + i] as i32) << 4) - b;
            }
        }
        sorted[..pixels].copy_from_slice(&values[..pixels]);
        sorted[..pixels].sort_unstable();
        let level = sorted[pixels - 1 - n];
        let mut moments = Moments::ZERO;
        for (k, &p) in values[..pixels].iter().enumerate() {
            moments.add((p - level).max(0), (k % side) as u16, (k / side) as u16);
        }
        let index = gy * grid.across + sx;
        out[index] = centroider.result(index as u16, moments, side as u16, side as u16);
    }
}

/// The level `v(N+1)` of each window of `frame`, by sorting (the floor's
/// known levels; untimed). Out of line: its frame (a window's values, ~4
/// KiB) inlined into the board's bench runner took that past the
/// STM32H743's stack guard (`scripts/board-memory`).
#[inline(never)]
pub fn levels(frame: &[u16], background: Option<&[i32]>, grid: Grid, n: usize, out: &mut [i32]) {
    const MAX: usize = 32 * 32;
    let (side, width) = (grid.side, grid.width());
    let pixels = side * side;
    let mut values = [0i32; MAX];
    for gy in 0..grid.across {
        for sx in 0..grid.across {
            for j in 0..side {
                let at = (gy * side + j) * width + sx * side;
                for (i, v) in values[j * side..][..side].iter_mut().enumerate() {
                    let b = background.map_or(0, |b| b[at + i]);
                    *v = ((frame[at + i] as i32) << 4) - b;
                }
            }
            let v = &mut values[..pixels];
            out[gy * grid.across + sx] = if n < pixels {
                *v.select_nth_unstable(pixels - 1 - n).1
            } else {
                i32::MIN
            };
        }
    }
}
