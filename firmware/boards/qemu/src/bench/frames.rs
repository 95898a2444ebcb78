//! Deterministic frames, generated on the device: Shack-Hartmann-like spots
//! and the patterns that stress a selection (a ramp, flat noise, all equal).
//!
//! A spot frame has a Gaussian spot per sub-aperture (200 photons, sigma
//! 1.5 px) at a random offset of up to +-3 px from the window's centre
//! (+-1 px in windows under 12 px), 50 counts of background and +-3 counts
//! of uniform noise, rounded to the nearest count: the host benchmark's
//! frames, in f32.

use libm::{expf, floorf};

/// A regular grid of square windows from the camera's corner.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Grid {
    /// Windows across and down.
    pub across: usize,
    /// Window side, pixels.
    pub side: usize,
}

impl Grid {
    pub const fn width(&self) -> usize {
        self.across * self.side
    }
    pub const fn pixels(&self) -> usize {
        self.width() * self.width()
    }
    pub const fn windows(&self) -> usize {
        self.across * self.across
    }
}

/// How a frame's pixels are made.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pattern {
    /// A Gaussian spot in each window.
    Spots,
    /// In each window, values rising in raster order (1 count a pixel from
    /// 50): every new pixel is the brightest so far.
    Ramp,
    /// Background and noise, no spot.
    FlatNoise,
    /// Every pixel 50 counts.
    AllEqual,
}

const BACKGROUND: f32 = 50.0;
/// 200 photons / (2 pi sigma^2), sigma^2 = 2.25.
const PEAK: f32 = 200.0 / (2.0 * core::f32::consts::PI * 2.25);

/// xorshift64.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }

    /// Uniform in [0, 1).
    pub fn next(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 40) as f32 / (1u32 << 24) as f32
    }
}

/// Frames of one grid and pattern, generated one camera row at a time (so
/// that cameras larger than RAM can be streamed).
pub struct Generator {
    rng: Rng,
    grid: Grid,
    pattern: Pattern,
    /// Spot centres of the current row of windows.
    centres: [(f32, f32); 128],
}

impl Generator {
    pub fn new(seed: u64, grid: Grid, pattern: Pattern) -> Self {
        assert!(grid.across <= 128);
        Generator {
            rng: Rng::new(seed),
            grid,
            pattern,
            centres: [(0.0, 0.0); 128],
        }
    }

    /// Camera row `y` of the current frame; rows come in order from 0, and
    /// after the last row of a frame the next frame starts.
    pub fn row(&mut self, y: usize, out: &mut [u16]) {
        let side = self.grid.side;
        let j = y % side;
        if j == 0 && self.pattern == Pattern::Spots {
            let reach = if side >= 12 { 3.0 } else { 1.0 };
            let middle = (side as f32 - 1.0) / 2.0;
            for c in &mut self.centres[..self.grid.across] {
                let cx = middle + (self.rng.next() - 0.5) * 2.0 * reach;
                let cy = middle + (self.rng.next() - 0.5) * 2.0 * reach;
                *c = (cx, cy);
            }
        }
        for (sx, part) in out.chunks_exact_mut(side).enumerate() {
            let (cx, cy) = self.centres[sx];
            for (i, p) in part.iter_mut().enumerate() {
                let v = match self.pattern {
                    Pattern::Spots => {
                        let (dx, dy) = (i as f32 - cx, j as f32 - cy);
                        BACKGROUND
                            + PEAK * expf(-(dx * dx + dy * dy) / 4.5)
                            + (self.rng.next() - 0.5) * 6.0
                    }
                    Pattern::Ramp => BACKGROUND + (j * side + i) as f32,
                    Pattern::FlatNoise => BACKGROUND + (self.rng.next() - 0.5) * 6.0,
                    Pattern::AllEqual => BACKGROUND,
                };
                *p = floorf(v + 0.5) as u16;
            }
        }
    }

    /// A whole frame into `frame` (row-major, the grid's camera).
    pub fn frame(&mut self, frame: &mut [u16]) {
        let width = self.grid.width();
        for (y, row) in frame.chunks_exact_mut(width).enumerate() {
            self.row(y, row);
        }
    }
}
