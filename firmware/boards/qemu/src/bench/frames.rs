//! Deterministic Shack-Hartmann-like frames, generated on the device: a
//! Gaussian spot per sub-aperture (200 photons, sigma 1.5 px) at a random
//! offset of up to +-3 px, 50 counts of background, +-3 counts of uniform
//! noise, rounded to the nearest count (the host benchmark's frames, in f32).

use libm::{expf, floorf};

/// Sub-aperture side, pixels.
pub const SIDE: usize = 16;
pub const CANARY_ACROSS: usize = 7;
pub const CANARY_WIDTH: usize = SIDE * CANARY_ACROSS;
pub const CANARY_PIXELS: usize = CANARY_WIDTH * CANARY_WIDTH;
pub const ELT_ACROSS: usize = 80;
pub const ELT_WIDTH: usize = SIDE * ELT_ACROSS;

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

    fn centre(&mut self) -> (f32, f32) {
        let cx = 7.5 + (self.next() - 0.5) * 6.0;
        let cy = 7.5 + (self.next() - 0.5) * 6.0;
        (cx, cy)
    }
}

/// One pixel at window coordinates (i, j) of a spot centred at (cx, cy).
fn pixel(rng: &mut Rng, i: usize, j: usize, (cx, cy): (f32, f32)) -> u16 {
    let dx = i as f32 - cx;
    let dy = j as f32 - cy;
    let v = BACKGROUND + PEAK * expf(-(dx * dx + dy * dy) / 4.5) + (rng.next() - 0.5) * 6.0;
    floorf(v + 0.5) as u16
}

/// A CANARY frame (112x112, 7x7 sub-apertures), row-major.
pub fn canary_frame(rng: &mut Rng, frame: &mut [u16]) {
    for sy in 0..CANARY_ACROSS {
        for sx in 0..CANARY_ACROSS {
            let centre = rng.centre();
            for j in 0..SIDE {
                let row = (sy * SIDE + j) * CANARY_WIDTH + sx * SIDE;
                for i in 0..SIDE {
                    frame[row + i] = pixel(rng, i, j, centre);
                }
            }
        }
    }
}

/// An 80x80-sub-aperture frame (1280x1280), generated one row at a time
/// (it does not fit the RAM beside everything else).
pub struct EltFrame {
    rng: Rng,
    centres: [(f32, f32); ELT_ACROSS],
}

impl EltFrame {
    pub fn new(rng: Rng) -> Self {
        EltFrame {
            rng,
            centres: [(0.0, 0.0); ELT_ACROSS],
        }
    }

    /// Camera row `y`; rows must come in order from 0.
    pub fn row(&mut self, y: usize, out: &mut [u16]) {
        let j = y % SIDE;
        if j == 0 {
            for c in &mut self.centres {
                *c = self.rng.centre();
            }
        }
        for (sx, part) in out.chunks_exact_mut(SIDE).enumerate() {
            let centre = self.centres[sx];
            for (i, p) in part.iter_mut().enumerate() {
                *p = pixel(&mut self.rng, i, j, centre);
            }
        }
    }
}
