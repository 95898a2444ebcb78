//! What the host bench measures: a configuration and a cube of frames.
//!
//! The standard workloads use deterministic spot frames (one Gaussian spot
//! per window, 200 photons, sigma 1.5 px, at a random offset of up to 3/16
//! of the window from its centre, 50 counts of background, +-3 counts of
//! uniform noise): the model of the QEMU bench's frames, so the host and
//! board figures are of the same pixels. A user's configuration is measured
//! on the user's frames or on spots from the project's simulator.

use anyhow::{bail, Context, Result};
use brightpix_protocol::{Camera, LevelFilter, RegularGrid};
use std::path::Path;

use crate::config_file::ProcessingConfig;
use crate::io::{FrameShape, FrameSource};
use crate::simulator::{SimulationParams, Simulator};

/// The CANARY default: 112x112, 7x7 sub-apertures of 16x16, background map,
/// subtract-next N = 20 (`examples/canary.toml`).
pub const CANARY: &str = "canary-subtract-next-n20";
/// An OCAM2-class 240x240 camera with 15x15 sub-apertures of 16x16,
/// background map, subtract-next N = 20.
pub const OCAM240: &str = "ocam240-subtract-next-n20";
/// The same with the level filter (SPEC.md §4, gain 2^-3): the engine splits
/// bands of sub-apertures across cores instead of frames.
pub const OCAM240_LEVEL_FILTER: &str = "ocam240-level-filter-n20";
/// A user's configuration (`brightpix bench --config`).
pub const USER: &str = "user";

/// A configuration and its frames.
pub struct Workload {
    pub name: String,
    pub description: String,
    pub config: ProcessingConfig,
    pub shape: FrameShape,
    /// `shape.frames` raw frames, row-major, one after another.
    pub pixels: Vec<u16>,
}

impl Workload {
    /// A workload of `frames` spot frames of `config`.
    pub fn spots(name: &str, description: String, config: ProcessingConfig, frames: usize) -> Self {
        let pixels = spot_frames(&config, frames, 0x2545_f491_4f6c_dd1d);
        Workload {
            name: name.to_string(),
            description,
            shape: shape_of(&config.camera, frames),
            config,
            pixels,
        }
    }

    pub fn frame(&self, index: usize) -> &[u16] {
        let n = self.shape.pixels_per_frame();
        &self.pixels[index * n..(index + 1) * n]
    }

    pub fn frames(&self) -> impl Iterator<Item = &[u16]> {
        self.pixels.chunks_exact(self.shape.pixels_per_frame())
    }

    pub fn pixel_count(&self) -> usize {
        self.pixels.len()
    }
}

fn shape_of(camera: &Camera, frames: usize) -> FrameShape {
    FrameShape {
        frames,
        height: camera.height as usize,
        width: camera.width as usize,
    }
}

/// Frames for about `pixels` pixels of `camera`, at least `minimum`.
pub fn frames_for(camera: &Camera, pixels: usize, minimum: usize) -> usize {
    (pixels / camera.pixel_count().max(1)).max(minimum)
}

/// The standard workloads, each with about `pixels` pixels of frames.
pub fn standard(pixels: usize) -> Vec<Workload> {
    let canary = crate::sil::canary_config();
    let canary_frames = frames_for(&canary.camera, pixels, 8);
    let ocam = ocam240_config();
    let ocam_frames = frames_for(&ocam.camera, pixels, 8);
    let mut filtered = ocam.clone();
    filtered.level_filter = Some(LevelFilter { gain_shift: 3 });
    vec![
        Workload::spots(
            CANARY,
            "CANARY 112x112, 7x7 sub-apertures of 16x16, background map, subtract-next N=20".into(),
            canary,
            canary_frames,
        ),
        Workload::spots(
            OCAM240,
            "240x240 (OCAM2-class), 15x15 sub-apertures of 16x16, background map, subtract-next N=20"
                .into(),
            ocam,
            ocam_frames,
        ),
        Workload::spots(
            OCAM240_LEVEL_FILTER,
            "the same with the level filter (gain 2^-3): bands of sub-apertures across cores".into(),
            filtered,
            ocam_frames,
        ),
    ]
}

/// 240x240, 16-bit, 15x15 windows of 16x16, 50-count background map,
/// subtract-next N = 20.
pub fn ocam240_config() -> ProcessingConfig {
    let camera = Camera {
        width: 240,
        height: 240,
        bit_depth: 16,
    };
    let grid = RegularGrid {
        x: 0,
        y: 0,
        columns: 15,
        rows: 15,
        width: 16,
        height: 16,
        pitch_x: 16,
        pitch_y: 16,
    };
    let mut config = ProcessingConfig::from_grid(camera, grid, &[]);
    config.background = Some(vec![50 * 16; camera.pixel_count()]);
    config
}

/// xorshift64, uniform in [0, 1).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// `count` deterministic spot frames for `config` (see the module
/// documentation), clamped to the camera's bit depth.
pub fn spot_frames(config: &ProcessingConfig, count: usize, seed: u64) -> Vec<u16> {
    const BACKGROUND: f64 = 50.0;
    const PHOTONS: f64 = 200.0;
    const SIGMA2: f64 = 2.25;
    let camera = config.camera;
    let (width, height) = (camera.width as usize, camera.height as usize);
    let max = camera.max_raw() as f64;
    let mut rng = Rng(seed | 1);
    let mut pixels = Vec::with_capacity(count * width * height);
    let mut frame = vec![0f64; width * height];
    for _ in 0..count {
        for p in frame.iter_mut() {
            *p = BACKGROUND + (rng.next() - 0.5) * 6.0;
        }
        for w in &config.windows {
            let (ww, wh) = (w.width as f64, w.height as f64);
            let cx = (ww - 1.0) / 2.0 + (rng.next() - 0.5) * 6.0 * ww / 16.0;
            let cy = (wh - 1.0) / 2.0 + (rng.next() - 0.5) * 6.0 * wh / 16.0;
            for j in 0..w.height as usize {
                for i in 0..w.width as usize {
                    let r2 = (i as f64 - cx).powi(2) + (j as f64 - cy).powi(2);
                    let spot = PHOTONS / (2.0 * std::f64::consts::PI * SIGMA2)
                        * (-r2 / (2.0 * SIGMA2)).exp();
                    frame[(w.y as usize + j) * width + w.x as usize + i] += spot;
                }
            }
        }
        pixels.extend(frame.iter().map(|&v| v.round().clamp(0.0, max) as u16));
    }
    pixels
}

/// `count` frames for `config` from the project's simulator (the paper's
/// CANARY NGS conditions, spots sized to each window): a pool of simulated
/// spots per window size, each window of each frame a different one, on the
/// simulator's background elsewhere.
pub fn simulated_frames(config: &ProcessingConfig, count: usize, seed: u64) -> Result<Vec<u16>> {
    let camera = config.camera;
    let width = camera.width as usize;
    let mut sizes: Vec<u16> = config
        .windows
        .iter()
        .map(|w| w.width.max(w.height))
        .collect();
    sizes.sort_unstable();
    sizes.dedup();
    const POOL: usize = 97;
    let mut pools = Vec::new();
    let mut background = 0u16;
    for &size in &sizes {
        let params = SimulationParams {
            pixels_per_subaperture: size as u32,
            bit_depth: camera.bit_depth,
            ..SimulationParams::canary()
        };
        let sim = Simulator::new(params)
            .with_context(|| format!("simulating {size}x{size}-pixel spots"))?;
        background = sim.calibration_background().round() as u16;
        pools.push((size, sim.frames(seed, 0, POOL)));
    }
    let mut pixels = vec![background.min(camera.max_raw()); count * camera.pixel_count()];
    for (f, frame) in pixels.chunks_exact_mut(camera.pixel_count()).enumerate() {
        for (k, w) in config.windows.iter().enumerate() {
            let size = w.width.max(w.height);
            let pool = &pools
                .iter()
                .find(|(s, _)| *s == size)
                .expect("every size")
                .1;
            let spot = &pool[(f * config.windows.len() + k) * 31 % POOL];
            let side = spot.size;
            let (dx, dy) = (
                (side - w.width as usize) / 2,
                (side - w.height as usize) / 2,
            );
            for j in 0..w.height as usize {
                let from = &spot.raw[(dy + j) * side + dx..][..w.width as usize];
                let at = (w.y as usize + j) * width + w.x as usize;
                frame[at..at + w.width as usize].copy_from_slice(from);
            }
        }
    }
    Ok(pixels)
}

/// The user's configuration on the first `max_frames` frames of `path`, or
/// on `frames` simulated ones when no path is given.
pub fn user(config: ProcessingConfig, path: Option<&Path>, frames: usize) -> Result<Workload> {
    let camera = config.camera;
    let (pixels, description) = match path {
        Some(path) => {
            let mut source = FrameSource::open_for_camera(path, &camera)?;
            if source.is_empty() {
                bail!("{}: no frames", path.display());
            }
            let count = source.len().min(frames);
            let mut pixels = Vec::with_capacity(count * camera.pixel_count());
            let mut frame = Vec::new();
            for index in 0..count {
                source.read_frame_into(index, &mut frame)?;
                pixels.extend_from_slice(&frame);
            }
            (pixels, format!("{count} frame(s) of {}", path.display()))
        }
        None => (
            simulated_frames(&config, frames, 1)?,
            format!("{frames} simulated frames (CANARY NGS spots sized to the windows)"),
        ),
    };
    let count = pixels.len() / camera.pixel_count();
    Ok(Workload {
        name: USER.to_string(),
        description: format!(
            "{}x{}, {} sub-apertures, {}",
            camera.width,
            camera.height,
            config.windows.len(),
            description
        ),
        shape: shape_of(&camera, count),
        config,
        pixels,
    })
}
