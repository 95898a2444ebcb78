//! The workloads the benchmark measures, and how one is measured: the engine
//! and its floors on the same frames, pushed one camera row at a time.

use brightpix_firmware::camera::cut_at_row_end;
use brightpix_firmware::engine::calibrate::WindowBounds;
use brightpix_firmware::engine::centroid::Centroider;
use brightpix_firmware::engine::{Engine, EngineMemory, EngineStats, SubapertureResult};
use brightpix_protocol::{
    Calibration, Camera, Centroid, Config, LevelFilter, PixelCount, Selection, SelectionRule,
    SubapertureWindow,
};

use crate::camera_feed::CameraFeed;
use crate::floor::{read_every_pixel, Floor, FloorMode};
use crate::frames::{background_pattern, Generator, Grid, Pattern, DEFAULT_FLUX};
use crate::sort;
use crate::Counter;

/// One measured configuration.
#[derive(Clone, Copy, Debug)]
pub struct Workload {
    /// Its name in the JSON lines.
    pub name: &'static str,
    pub grid: Grid,
    pub pattern: Pattern,
    pub bit_depth: u8,
    pub rule: SelectionRule,
    pub n: u16,
    pub level_filter: Option<LevelFilter>,
    /// A background map (50 counts everywhere, as a map: the engine reads it).
    pub background: bool,
    /// The frames' background has `frames::background_pattern` (+-2
    /// counts), and so has the map.
    pub patterned_background: bool,
    /// Peak-to-peak uniform noise, counts (6: +-3).
    pub noise: f32,
    /// Photons in a spot ([`DEFAULT_FLUX`]: faint).
    pub flux: f32,
    /// Frames pushed before measuring (the seeds of a running camera).
    pub warmup: usize,
    /// Frames measured.
    pub frames: usize,
    /// Also measure the paper's sort per sub-aperture.
    pub sort: bool,
    /// Pixels pushed at a time (a camera source's runs, e.g.
    /// [`source_run`]); `None`: one camera row per push.
    pub chunk: Option<usize>,
    /// The frames reach the engine through the board's camera source, as
    /// the DMA writes them ([`CameraFeed`]: its runs and its copy out of
    /// the ring counted with the engine); `chunk` is then the source's.
    pub camera: bool,
}

/// The CANARY defaults: 7x7 windows of 16x16, subtract-next N = 20, a
/// background map, spot frames.
pub const CANARY: Workload = Workload {
    name: "canary-subtract-next-n20",
    grid: Grid {
        across: 7,
        side: 16,
    },
    pattern: Pattern::Spots,
    bit_depth: 16,
    rule: SelectionRule::SubtractNext,
    n: 20,
    level_filter: None,
    background: true,
    patterned_background: false,
    noise: 6.0,
    flux: DEFAULT_FLUX,
    warmup: 8,
    frames: 8,
    sort: true,
    chunk: None,
    camera: false,
};

/// The pixels of each run the board's camera source
/// (`brightpix_firmware::camera::DcmiSource`, 12-bit pixels two to a word)
/// delivers from a frame whose words are all there, at most `chunk` (at
/// least a row, even, like `width`): cut at the last row end it reaches
/// ([`cut_at_row_end`], the source's own rule), so whole rows, the same
/// number in every run but perhaps the frame's last.
pub const fn source_run(chunk: usize, width: usize) -> usize {
    2 * cut_at_row_end(0, (chunk / 2) as u32, (width / 2) as u32) as usize
}

/// Every workload of the speed issue.
pub const ALL: &[Workload] = &[
    CANARY,
    Workload {
        name: "canary-threshold-n20",
        rule: SelectionRule::Threshold,
        sort: false,
        ..CANARY
    },
    Workload {
        name: "canary-subtract-next-distinct-n20",
        rule: SelectionRule::SubtractNextDistinct,
        sort: false,
        ..CANARY
    },
    Workload {
        name: "canary-subtract-mean-m4-n20",
        rule: SelectionRule::SubtractMean { count: 4 },
        sort: false,
        ..CANARY
    },
    Workload {
        name: "canary-level-filter-n20",
        level_filter: Some(LevelFilter { gain_shift: 4 }),
        sort: false,
        ..CANARY
    },
    Workload {
        name: "canary-8bit-n20",
        bit_depth: 8,
        sort: false,
        ..CANARY
    },
    // As the STM32H743's DCMI source delivers them: 12-bit pixels in runs
    // of at most 512 words (1,024 pixels), cut at row ends: nine rows.
    Workload {
        name: "canary-12bit-runs-1024",
        bit_depth: 12,
        chunk: Some(source_run(
            2 * CAMERA_RUN_WORDS,
            CANARY.grid.across * CANARY.grid.side,
        )),
        sort: false,
        ..CANARY
    },
    // As the STM32H743 runs it: the same frames written to a DMA ring as
    // its DCMI packs them, taken out by its camera source (`DcmiSource`:
    // runs of at most 512 words cut at row ends, copied out of the ring
    // and read as pixels) and pushed run by run, all of it counted.
    Workload {
        name: "canary-12bit-dcmi",
        bit_depth: 12,
        camera: true,
        sort: false,
        ..CANARY
    },
    // Spots that move less than 0.3 px a frame, as in a closed loop.
    Workload {
        name: "canary-closed-loop",
        pattern: Pattern::ClosedLoopSpots,
        sort: false,
        ..CANARY
    },
    // Quieter pixels (+-1 count), and noisier ones (+-6) over a background
    // with a fixed +-2 pattern that the map corrects: noise near v(N+1) is
    // what sets the admissions.
    Workload {
        name: "canary-noise-1",
        noise: 2.0,
        sort: false,
        ..CANARY
    },
    Workload {
        name: "canary-noise-6-patterned",
        noise: 12.0,
        patterned_background: true,
        sort: false,
        ..CANARY
    },
    // Spots ten times brighter (peak ~140 counts): a count level of the
    // window then holds a few pixels, not ~20, which changes what the
    // seed's margin and the rescans cost.
    Workload {
        name: "canary-bright-x10",
        flux: 10.0 * DEFAULT_FLUX,
        sort: false,
        ..CANARY
    },
    Workload {
        name: "canary-n5",
        n: 5,
        sort: false,
        ..CANARY
    },
    Workload {
        name: "canary-n60",
        n: 60,
        sort: false,
        ..CANARY
    },
    // DARC's rule at a larger N: its ends select `v(N)` among the ties
    // above the previous level, which N = 20 alone would not show.
    Workload {
        name: "canary-subtract-next-distinct-n60",
        rule: SelectionRule::SubtractNextDistinct,
        n: 60,
        sort: false,
        ..CANARY
    },
    Workload {
        name: "canary-n200",
        n: 200,
        sort: false,
        ..CANARY
    },
    Workload {
        name: "canary-no-selection",
        n: 256,
        sort: false,
        ..CANARY
    },
    Workload {
        name: "windows-8x8-n20",
        grid: Grid {
            across: 14,
            side: 8,
        },
        sort: false,
        ..CANARY
    },
    Workload {
        name: "windows-32x32-n20",
        grid: Grid {
            across: 4,
            side: 32,
        },
        sort: false,
        ..CANARY
    },
    Workload {
        name: "ramp-n20",
        pattern: Pattern::Ramp,
        sort: false,
        ..CANARY
    },
    Workload {
        name: "flat-noise-n20",
        pattern: Pattern::FlatNoise,
        sort: false,
        ..CANARY
    },
    Workload {
        name: "all-equal-n20",
        pattern: Pattern::AllEqual,
        sort: false,
        ..CANARY
    },
    Workload {
        name: "elt-800-10x10-n20",
        grid: Grid {
            across: 80,
            side: 10,
        },
        background: false,
        warmup: 1,
        frames: 1,
        sort: false,
        ..CANARY
    },
];

/// Largest camera side of the workloads (the ELT-like 800).
pub const MAX_WIDTH: usize = 800;
pub const MAX_PIXELS: usize = MAX_WIDTH * MAX_WIDTH;
/// Largest background map (the 128x128 camera of 32x32 windows).
pub const MAX_MAP_PIXELS: usize = 128 * 128;
pub const MAX_WINDOWS: usize = 80 * 80;

/// What one workload measured, in instructions.
#[derive(Clone, Copy, Debug, Default)]
pub struct Measured {
    pub pixels: usize,
    pub frames: usize,
    pub engine: f64,
    /// The engine on the final camera row of a frame, mean.
    pub engine_last_row: f64,
    pub floor: f64,
    pub floor_last_row: f64,
    pub calibrate_all: f64,
    pub memory: f64,
    pub sort: Option<f64>,
    pub sort_last_row: Option<f64>,
    pub stats: EngineStats,
}

/// One measured frame's counts (a board's bench request reports their
/// minimum, median and maximum; `device::Recorder` collects them).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameCounts {
    pub engine: f64,
    /// The pushes that carry the frame's last camera row.
    pub engine_last_row: f64,
    pub floor: f64,
    pub floor_last_row: f64,
}

impl Workload {
    /// Whether the floor does the engine's arithmetic (subtract-next, or
    /// no selection, without level filter): [`measure`] then checks their
    /// slopes are equal on every frame.
    pub fn floor_comparable(&self) -> bool {
        let selects = (self.n as usize) < self.grid.side * self.grid.side;
        (self.rule == SelectionRule::SubtractNext || !selects) && self.level_filter.is_none()
    }
}

impl Measured {
    pub fn per_pixel(&self, instructions: f64) -> f64 {
        instructions / self.pixels as f64
    }
}

/// The camera source's run buffers as the STM32H743's camera path has
/// them (its `storage::RUN_WORDS` and `RUN_PIXELS`, which it asserts equal
/// to these): runs of up to 512 words, 1,024 pixels to unpack 8-bit words
/// into (256 words of four). 10- to 16-bit words are read in place
/// (`camera::packing::as_pixels`), two pixels each: runs of 512 words,
/// about nine rows of a CANARY camera (112 pixels), cut at a row end.
pub const CAMERA_RUN_WORDS: usize = 512;
pub const CAMERA_RUN_PIXELS: usize = 1024;

/// Buffers a workload runs in, from statics.
pub struct Buffers<'b> {
    pub frame: &'b mut [u16],
    pub background: &'b mut [i32],
    pub windows: &'b mut [SubapertureWindow],
    pub levels: &'b mut [i32],
    pub bounds: &'b mut [WindowBounds],
    pub engine_results: &'b mut [SubapertureResult],
    pub floor_results: &'b mut [SubapertureResult],
    /// The camera source's run buffers (a workload with `camera`), as the
    /// STM32H743's ([`CAMERA_RUN_WORDS`], [`CAMERA_RUN_PIXELS`]).
    pub camera_words: &'b mut [u32],
    pub camera_pixels: &'b mut [u16],
}

/// [`Mismatch::what`] when the engine's memory refused the workload.
pub const ENGINE_REFUSED: &str = "the engine refused the workload's configuration";

/// The results differ where both should be bit-identical.
#[derive(Debug)]
pub struct Mismatch {
    pub what: &'static str,
    pub index: usize,
}

pub fn config<'a>(
    w: &Workload,
    windows: &'a [SubapertureWindow],
    background: Option<&'a [i32]>,
) -> Config<'a> {
    let width = w.grid.width() as u16;
    Config {
        camera: Camera {
            width,
            height: width,
            bit_depth: w.bit_depth,
        },
        windows,
        calibration: Calibration {
            background,
            ..Calibration::default()
        },
        selection: Selection {
            rule: w.rule,
            count: PixelCount::All(w.n),
            level_filter: w.level_filter,
        },
        centroid: Centroid::default(),
        crop: None,
    }
}

/// Measures `w`: the engine, its floors and, if asked, the sort, on the
/// same frames. Checks the floor's slopes equal the engine's where they do
/// the same arithmetic (subtract-next without level filter), and the
/// sort's. `A`: the widest grid row the floor holds (at least
/// `w.grid.across`).
///
/// Every frame, in this order: `meter.between_frames()`, then four
/// counts: the engine's pushes (camera rows, or `w.chunk` pixels) before
/// those that carry the frame's last row, those pushes, the floor's rows
/// before the last, its last row; then the other floors' and the sort's
/// (`device::Recorder` relies on this order). The code of this function is
/// the QEMU tables': a change here moves the instructions around the timed
/// calls.
///
/// In the QEMU bench binary (`cfg(brightpix_qemu_bench)`) it counts with
/// that binary's `Meter` by name: generic over the counter, rustc cannot
/// inline the counter into this function before LLVM sees it, and the
/// code around the timed calls changes (the CANARY engine figure by 0.009
/// instr/px, its last row by 1): the QEMU tables stay as they were.
pub fn measure<#[cfg(not(brightpix_qemu_bench))] C: Counter, const A: usize>(
    w: &Workload,
    #[cfg(not(brightpix_qemu_bench))] meter: &C,
    #[cfg(brightpix_qemu_bench)] meter: &crate::meter::Meter,
    b: &mut Buffers<'_>,
    memory: EngineMemory<'_>,
) -> Result<Measured, Mismatch> {
    let grid = w.grid;
    let (width, pixels) = (grid.width(), grid.pixels());
    let windows = &mut b.windows[..grid.windows()];
    for (k, window) in windows.iter_mut().enumerate() {
        *window = SubapertureWindow {
            x: ((k % grid.across) * grid.side) as u16,
            y: ((k / grid.across) * grid.side) as u16,
            width: grid.side as u16,
            height: grid.side as u16,
        };
    }
    let background = if w.background {
        let map = &mut b.background[..pixels];
        for (k, value) in map.iter_mut().enumerate() {
            let pattern = if w.patterned_background {
                background_pattern(k % width, k / width)
            } else {
                0
            };
            *value = (50 + pattern) * 16;
        }
        Some(&*map)
    } else {
        None
    };
    let config = config(w, windows, background);
    let Ok(mut engine) = Engine::new(config, memory) else {
        return Err(Mismatch {
            what: ENGINE_REFUSED,
            index: 0,
        });
    };
    for (bounds, window) in b.bounds.iter_mut().zip(windows.iter()) {
        *bounds = WindowBounds::of(&config, window);
    }
    let centroider = Centroider::new(Centroid::default());
    let frame = &mut b.frame[..pixels];
    let mut generator = Generator::new(0x2545_f491_4f6c_dd1d, grid, w.pattern)
        .with_noise(w.noise)
        .with_flux(w.flux)
        .with_patterned_background(w.patterned_background);
    for _ in 0..w.warmup {
        generator.frame(frame);
        for row in frame.chunks_exact(width) {
            let _ = engine.push(row, &mut |_r: SubapertureResult| {});
        }
    }
    let mut feed = if w.camera {
        let feed = CameraFeed::new(config.camera, frame, b.camera_words, b.camera_pixels);
        if feed.is_none() {
            return Err(Mismatch {
                what: "the camera source cannot carry the workload's frames",
                index: 0,
            });
        }
        feed
    } else {
        None
    };
    let before = engine.stats();
    let mut m = Measured {
        pixels: pixels * w.frames,
        frames: w.frames,
        ..Measured::default()
    };
    let selects = (w.n as usize) < grid.side * grid.side;
    for _ in 0..w.frames {
        meter.between_frames();
        generator.frame(frame);
        sort::levels(frame, background, grid, w.n as usize, b.levels);
        // The engine: rows, or runs of `chunk` pixels across rows, counted
        // in two parts, the pushes before those that carry the frame's last
        // row, and those: a count per push would add the counter's own
        // error (a few instructions, which the compiler moves with
        // unrelated code) a hundred times a frame.
        let results = &mut *b.engine_results;
        if let Some(feed) = feed.as_mut() {
            let (count, last_row) = camera_frame(meter, feed, frame, &mut engine, results)?;
            m.engine += count;
            m.engine_last_row += last_row / w.frames as f64;
        } else {
            let step = w.chunk.unwrap_or(width);
            let first_of_last_row = (pixels - width) / step;
            let (before_last_row, last_row) = frame.split_at(first_of_last_row * step);
            let mut pushes = |part: &[u16], first: usize| {
                meter.count(|| {
                    for (c, run) in part.chunks(step).enumerate() {
                        let pushed = engine.push(run, &mut |r: SubapertureResult| {
                            results[r.index as usize] = r
                        });
                        if pushed.is_err() {
                            return Err(Mismatch {
                                what: "the engine refused a generated pixel",
                                index: first + c,
                            });
                        }
                    }
                    Ok(())
                })
            };
            let (count, pushed) = pushes(before_last_row, 0);
            pushed?;
            m.engine += count;
            let (count, pushed) = pushes(last_row, first_of_last_row);
            pushed?;
            m.engine += count;
            m.engine_last_row += count / w.frames as f64;
        }
        // The floor, and its slopes against the engine's.
        let mode = if selects {
            FloorMode::Skip
        } else {
            FloorMode::AllPixels
        };
        let mut floor = Floor::<A>::new(
            grid,
            config.calibration,
            centroider,
            mode,
            b.levels,
            b.bounds,
        );
        // Counted as the engine is: the rows before the last, and the last.
        // One sink for both, so that both run the same instance of
        // `push_row`.
        let floor_results = &mut *b.floor_results;
        let mut out = |r: SubapertureResult| floor_results[r.index as usize] = r;
        let (before_last_row, last_row) = frame.split_at(pixels - width);
        let (count, ()) = meter.count(|| {
            for (y, row) in before_last_row.chunks_exact(width).enumerate() {
                floor.push_row(y, row, &mut out);
            }
        });
        m.floor += count;
        let (count, ()) = meter.count(|| floor.push_row(pixels / width - 1, last_row, &mut out));
        m.floor += count;
        m.floor_last_row += count / w.frames as f64;
        let same_arithmetic =
            (w.rule == SelectionRule::SubtractNext || !selects) && w.level_filter.is_none();
        if same_arithmetic {
            if let Some(index) =
                (0..grid.windows()).find(|&k| b.engine_results[k] != b.floor_results[k])
            {
                return Err(Mismatch {
                    what: "the floor's slopes differ from the engine's",
                    index,
                });
            }
        }
        // The floor as first defined: every pixel calibrated.
        if selects {
            let mut all = Floor::<A>::new(
                grid,
                config.calibration,
                centroider,
                FloorMode::CalibrateAll,
                b.levels,
                b.bounds,
            );
            let (count, ()) = meter.count(|| {
                for (y, row) in frame.chunks_exact(width).enumerate() {
                    all.push_row(y, row, &mut |_r: SubapertureResult| {});
                }
            });
            m.calibrate_all += count;
        }
        // Every pixel read once.
        let (count, ()) = meter.count(|| {
            for row in frame.chunks_exact(width) {
                core::hint::black_box(read_every_pixel(core::hint::black_box(row)));
            }
        });
        m.memory += count;
        // The paper's method.
        if w.sort {
            let sorted = &mut *b.floor_results;
            let (mut total, mut last) = (0.0, 0.0);
            for gy in 0..grid.across {
                let (count, ()) = meter.count(|| {
                    sort::sort_grid_row(
                        frame,
                        background,
                        grid,
                        gy,
                        w.n as usize,
                        &centroider,
                        sorted,
                    )
                });
                total += count;
                if gy == grid.across - 1 {
                    last = count;
                }
            }
            *m.sort.get_or_insert(0.0) += total;
            *m.sort_last_row.get_or_insert(0.0) += last / w.frames as f64;
            if let Some(index) = (0..grid.windows()).find(|&k| b.engine_results[k] != sorted[k]) {
                return Err(Mismatch {
                    what: "the sort's slopes differ from the engine's",
                    index,
                });
            }
        }
    }
    let after = engine.stats();
    m.stats = EngineStats {
        windows: after.windows - before.windows,
        candidates: after.candidates - before.candidates,
        compactions: after.compactions - before.compactions,
        rescans: after.rescans - before.rescans,
        attentions: after.attentions - before.attentions,
        kernel_frames: after.kernel_frames - before.kernel_frames,
    };
    Ok(m)
}

/// One frame of `w.camera` workloads through the board's camera path: the
/// DMA writes all rows but the last, the source's runs go to the engine;
/// then the last row and the frame's end mark. The engine's count over the
/// frame, and over the pushes that carry the last row. Out of line, so
/// that [`measure`]'s code around the other workloads' counted calls stays
/// as it was (inlined, it moved every other row of the tables by 0.01
/// instructions a pixel and its last row by about 2).
#[inline(never)]
fn camera_frame(
    meter: &impl Counter,
    feed: &mut CameraFeed<'_>,
    frame: &[u16],
    engine: &mut Engine<'_, '_>,
    results: &mut [SubapertureResult],
) -> Result<(f64, f64), Mismatch> {
    let mut sink = |r: SubapertureResult| results[r.index as usize] = r;
    let refused = |_| Mismatch {
        what: "the engine refused a pixel of the camera source",
        index: 0,
    };
    feed.arrive_before_last_row(frame);
    let (before, pushed) = meter.count(|| feed.drain(|run| engine.push(run, &mut sink)));
    pushed.map_err(refused)?;
    feed.arrive_last_row();
    let (last_row, pushed) = meter.count(|| feed.drain(|run| engine.push(run, &mut sink)));
    pushed.map_err(refused)?;
    Ok((before + last_row, last_row))
}
