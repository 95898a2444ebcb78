//! A whole Shack-Hartmann camera: every window's sub-aperture simulated
//! with its own parameters (lit fraction, LGS elongation, photons) and
//! pasted into one frame, the pixels outside every window carrying the
//! background and read noise only. This is the frame generator for recorded
//! cubes, tests and the Python bindings: it returns the camera frames and
//! each window's noiseless ("true") slope.

use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use super::{stream_rng, SimError, SimulationParams, Simulator, SpotFrame};

/// One window of the camera and what its sub-aperture sees.
#[derive(Clone, Debug)]
pub struct CameraWindow {
    /// Top-left corner on the camera (pixels); the window's side is
    /// `params.pixels_per_subaperture`.
    pub x: usize,
    pub y: usize,
    pub params: SimulationParams,
}

/// One camera frame.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraFrame {
    /// `width * height` counts, row-major.
    pub raw: Vec<u16>,
    /// Per window, the centre of gravity of its noiseless image (pixels from
    /// the window's centre, `[x, y]`).
    pub true_slopes: Vec<[f64; 2]>,
    /// Per window, the G-tilt of its lenslet's wavefront (the slope an
    /// untruncated, noiseless spot would give; [`SpotFrame::phase_slope`]).
    ///
    /// [`SpotFrame::phase_slope`]: super::SpotFrame::phase_slope
    pub phase_slopes: Vec<[f64; 2]>,
}

/// The camera simulator (immutable, `Sync`).
pub struct CameraSimulator {
    width: usize,
    height: usize,
    windows: Vec<(usize, usize, Simulator)>,
    /// Background (counts), read noise (e-), gain (e-/count), the largest
    /// count: for the pixels outside every window.
    background: f64,
    read_noise_e: f64,
    gain: f64,
    max_count: f64,
}

impl CameraSimulator {
    /// A `width x height` camera; the pixels outside the windows take the
    /// background, read noise, gain and bit depth of the first window.
    pub fn new(width: usize, height: usize, windows: Vec<CameraWindow>) -> Result<Self, SimError> {
        let first = windows
            .first()
            .ok_or_else(|| SimError::Invalid("a camera needs at least one window".into()))?
            .params
            .clone();
        let mut sims = Vec::with_capacity(windows.len());
        for (k, w) in windows.into_iter().enumerate() {
            let size = w.params.pixels_per_subaperture as usize;
            if w.x + size > width || w.y + size > height {
                return Err(SimError::Invalid(format!(
                    "window {k} at ({}, {}) of {size} pixels leaves the {width}x{height} camera",
                    w.x, w.y
                )));
            }
            sims.push((w.x, w.y, Simulator::new(w.params)?));
        }
        Ok(Self {
            width,
            height,
            windows: sims,
            background: first.background + first.background_error,
            read_noise_e: first.read_noise_e,
            gain: first.gain_e_per_count,
            max_count: ((1u32 << first.bit_depth) - 1) as f64,
        })
    }

    /// Frame `index` of run `seed`. Each window's sub-aperture is frame
    /// `index * windows + k` of its own simulator: independent turbulence
    /// and noise per window and frame.
    pub fn frame(&self, seed: u64, index: u64) -> CameraFrame {
        let count = self.windows.len() as u64;
        self.assemble(seed, index, &mut |k, sim| {
            sim.subaperture_frame(index * count + k as u64, seed)
        })
    }

    /// Frame `index` of run `seed` through a given atmosphere: `opd(k, sim,
    /// buffer)` fills `buffer` with window `k`'s lenslet optical path
    /// difference (metres, on `sim`'s [`Simulator::phase_sampling`] grid,
    /// row-major `[y][x]`), e.g. cut from a layered atmosphere in the
    /// wavefront sensor's direction. Photon, read and background noise come
    /// from the same streams as [`CameraSimulator::frame`]'s.
    pub fn frame_from_opds(
        &self,
        seed: u64,
        index: u64,
        opd: &mut dyn FnMut(usize, &Simulator, &mut Vec<f64>),
    ) -> CameraFrame {
        let count = self.windows.len() as u64;
        let mut ws = super::Workspace::default();
        let mut buffer = Vec::new();
        self.assemble(seed, index, &mut |k, sim| {
            let (n, _) = sim.phase_sampling();
            buffer.clear();
            buffer.resize(n * n, 0.0);
            opd(k, sim, &mut buffer);
            sim.frame_from_opd(&mut ws, &buffer, index * count + k as u64, seed)
        })
    }

    /// The windows (top-left corner on the camera, and their simulators).
    pub fn windows(&self) -> impl Iterator<Item = (usize, usize, &Simulator)> {
        self.windows.iter().map(|(x, y, sim)| (*x, *y, sim))
    }

    /// The camera's width and height (pixels).
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Frame `index`: the pixels outside the windows, then each window's
    /// spot from `spot(k, simulator)` pasted in.
    fn assemble(
        &self,
        seed: u64,
        index: u64,
        spot: &mut dyn FnMut(usize, &Simulator) -> SpotFrame,
    ) -> CameraFrame {
        let mut rng = stream_rng(seed, index, 2);
        let raw: Vec<u16> = (0..self.width * self.height)
            .map(|_| {
                let n: f64 = StandardNormal.sample(&mut rng);
                (self.background + self.read_noise_e * n / self.gain)
                    .round()
                    .clamp(0.0, self.max_count) as u16
            })
            .collect();
        let mut frame = CameraFrame {
            raw,
            true_slopes: Vec::with_capacity(self.windows.len()),
            phase_slopes: Vec::with_capacity(self.windows.len()),
        };
        for (k, (x0, y0, sim)) in self.windows.iter().enumerate() {
            let spot = spot(k, sim);
            let size = spot.size;
            for y in 0..size {
                let row = (y0 + y) * self.width + x0;
                frame.raw[row..row + size].copy_from_slice(&spot.raw[y * size..(y + 1) * size]);
            }
            frame.true_slopes.push(spot.true_slope);
            frame.phase_slopes.push(spot.phase_slope);
        }
        frame
    }

    /// Frames `first .. first + count`, in parallel; identical to
    /// [`CameraSimulator::frame`] one by one.
    pub fn frames(&self, seed: u64, first: u64, count: usize) -> Vec<CameraFrame> {
        (0..count)
            .into_par_iter()
            .map(|i| self.frame(seed, first + i as u64))
            .collect()
    }
}
