//! Deterministic frames, generated on the device: Shack-Hartmann-like spots
//! and the patterns that stress a selection (a ramp, flat noise, all equal).
//!
//! A spot frame has a Gaussian spot per sub-aperture (200 photons, sigma
//! 1.5 px) at a random offset of up to +-3 px from the window's centre
//! (+-1 px in windows under 12 px), 50 counts of background and +-3 counts
//! of uniform noise, rounded to the nearest count: the host benchmark's
//! frames, in f32. Variants a reviewer could ask for: closed-loop spots
//! (each moves less than 0.3 px a frame), another noise amplitude, and a
//! fixed pattern of +-2 counts in the background (which the workload's
//! background map then holds, as a dark frame would).

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
    /// A Gaussian spot in each window, anywhere in its range every frame.
    Spots,
    /// As `Spots`, but each spot moves by less than 0.3 px in x and y
    /// between frames (a random walk kept in range): a closed loop.
    ClosedLoopSpots,
    /// In each window, values rising in raster order (1 count a pixel from
    /// 50): every new pixel is the brightest so far.
    Ramp,
    /// Background and noise, no spot.
    FlatNoise,
    /// Every pixel 50 counts.
    AllEqual,
}

const BACKGROUND: f32 = 50.0;

/// Windows whose spots a closed-loop generator remembers between frames.
pub const MAX_CLOSED_LOOP_WINDOWS: usize = 256;

/// The fixed background pattern at camera pixel (x, y), -2 to +2 counts:
/// added to the frames' background and held by the background map of a
/// workload with a patterned background.
pub fn background_pattern(x: usize, y: usize) -> i32 {
    ((x * 7 + y * 13) % 5) as i32 - 2
}
/// Photons in a spot by default: a faint guide star, the paper's regime
/// (peak ~14 counts over +-3 of noise).
pub const DEFAULT_FLUX: f32 = 200.0;

/// A Gaussian spot's peak for `flux` photons: flux / (2 pi sigma^2),
/// sigma^2 = 2.25.
fn peak(flux: f32) -> f32 {
    flux / (2.0 * core::f32::consts::PI * 2.25)
}

/// xorshift64.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }

    /// Uniform in [0, 1).
    #[allow(clippy::should_implement_trait)]
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
    /// Peak-to-peak amplitude of the uniform noise, counts.
    noise: f32,
    /// A spot's peak above the background, counts.
    peak: f32,
    /// Whether the background has [`background_pattern`].
    patterned: bool,
    /// Spot centres of the current row of windows.
    centres: [(f32, f32); 128],
    /// Closed loop: every window's spot offset from its window's centre,
    /// kept from frame to frame.
    offsets: [(f32, f32); MAX_CLOSED_LOOP_WINDOWS],
    /// Frames started (a closed loop places its spots at random in the
    /// first).
    frames: usize,
}

impl Generator {
    pub fn new(seed: u64, grid: Grid, pattern: Pattern) -> Self {
        assert!(grid.across <= 128);
        assert!(pattern != Pattern::ClosedLoopSpots || grid.windows() <= MAX_CLOSED_LOOP_WINDOWS);
        Generator {
            rng: Rng::new(seed),
            grid,
            pattern,
            noise: 6.0,
            peak: peak(DEFAULT_FLUX),
            patterned: false,
            centres: [(0.0, 0.0); 128],
            offsets: [(0.0, 0.0); MAX_CLOSED_LOOP_WINDOWS],
            frames: 0,
        }
    }

    /// Uniform noise of `peak_to_peak` counts (6 by default: +-3).
    pub fn with_noise(mut self, peak_to_peak: f32) -> Self {
        self.noise = peak_to_peak;
        self
    }

    /// Spots of `photons` in all ([`DEFAULT_FLUX`] by default).
    pub fn with_flux(mut self, photons: f32) -> Self {
        self.peak = peak(photons);
        self
    }

    /// Adds [`background_pattern`] to every pixel.
    pub fn with_patterned_background(mut self, patterned: bool) -> Self {
        self.patterned = patterned;
        self
    }

    /// The spot centres of grid row `row` for the frame starting now.
    fn place_spots(&mut self, row: usize) {
        let side = self.grid.side;
        let reach = if side >= 12 { 3.0 } else { 1.0 };
        let middle = (side as f32 - 1.0) / 2.0;
        let across = self.grid.across;
        for k in 0..across {
            let (dx, dy) = match self.pattern {
                Pattern::ClosedLoopSpots if self.frames > 1 => {
                    // Steps of less than 0.3 px, kept within reach.
                    let (x, y) = self.offsets[row * across + k];
                    let step = |v: f32, u: f32| (v + (u - 0.5) * 0.58).clamp(-reach, reach);
                    (step(x, self.rng.next()), step(y, self.rng.next()))
                }
                _ => (
                    (self.rng.next() - 0.5) * 2.0 * reach,
                    (self.rng.next() - 0.5) * 2.0 * reach,
                ),
            };
            if self.pattern == Pattern::ClosedLoopSpots {
                self.offsets[row * across + k] = (dx, dy);
            }
            self.centres[k] = (middle + dx, middle + dy);
        }
    }

    /// Camera row `y` of the current frame; rows come in order from 0, and
    /// after the last row of a frame the next frame starts.
    pub fn row(&mut self, y: usize, out: &mut [u16]) {
        let side = self.grid.side;
        let j = y % side;
        if y == 0 {
            self.frames += 1;
        }
        if j == 0 && matches!(self.pattern, Pattern::Spots | Pattern::ClosedLoopSpots) {
            self.place_spots(y / side);
        }
        let (noise, peak) = (self.noise, self.peak);
        for (sx, part) in out.chunks_exact_mut(side).enumerate() {
            let (cx, cy) = self.centres[sx];
            for (i, p) in part.iter_mut().enumerate() {
                let background = if self.patterned {
                    BACKGROUND + background_pattern(sx * side + i, y) as f32
                } else {
                    BACKGROUND
                };
                let v = match self.pattern {
                    Pattern::Spots | Pattern::ClosedLoopSpots => {
                        let (dx, dy) = (i as f32 - cx, j as f32 - cy);
                        background
                            + peak * expf(-(dx * dx + dy * dy) / 4.5)
                            + (self.rng.next() - 0.5) * noise
                    }
                    Pattern::Ramp => background + (j * side + i) as f32,
                    Pattern::FlatNoise => background + (self.rng.next() - 0.5) * noise,
                    Pattern::AllEqual => background,
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
