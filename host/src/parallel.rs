//! All cores on the host: a batch of frames through the firmware's streaming
//! engine, with results bit-identical to [`HostEngine`] fed the same frames
//! one after another (the property tests in `tests/tests/parallel_engine.rs`
//! check it, level filter and per-sub-aperture N included).
//!
//! ```
//! use brightpix::io::FrameShape;
//! use brightpix::parallel::ParallelEngine;
//! # let config = brightpix::sil::canary_config();
//! # let pixels = vec![60u16; 3 * 112 * 112];
//! let mut engine = ParallelEngine::new(&config.view(), None)?; // None: all cores
//! let shape = FrameShape { frames: 3, height: 112, width: 112 };
//! let results = engine.process(&pixels, shape)?;
//! let [x, y] = results.slopes[2 * results.subapertures + 5]; // frame 2, sub-aperture 5, 2^-16 px
//! # let _ = (x, y);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! # How the work is split
//! - **Frames.** Without the level filter (SPEC.md §4) frames are independent:
//!   each worker takes runs of consecutive frames with engine memory of its own.
//! - **Bands of sub-aperture rows.** With the level filter, a sub-aperture's
//!   result depends on its own earlier frames, and on nothing else: §2-§5 are
//!   per sub-aperture. The windows, in raster order of their first pixel, are
//!   cut into one band per thread of about equal pixel count. A band is a
//!   configuration of its own over the camera rows its windows span (maps,
//!   N and reference slopes cut to match), with its own engine memory and
//!   level-filter state, and goes through the batch's frames in order,
//!   reading its rows of each frame in place (a run of whole rows is
//!   contiguous: nothing is copied). Batches of fewer frames than threads are
//!   split the same way.
//!
//! What limits the bands: every band walks every frame, so their number is at
//! most the number of windows; overlapping windows that fall in two bands
//! have their shared rows read by both; bands are balanced by pixel count
//! (what selection costs), and a band whose pixels are harder (brighter, more
//! heap inserts) finishes last.
//!
//! # Bad frames
//! A pixel above the camera's bit depth anywhere in a batch rejects the whole
//! batch before any frame is processed ([`BatchError::Pixel`] names the frame,
//! row and column): nothing is written and no level-filter state changes. (A
//! [`HostEngine`] fed the same frames would have completed the frames and
//! sub-apertures before the bad pixel, SPEC.md §8; a batch is accepted whole
//! or not at all.)
//!
//! [`HostEngine`]: crate::engine_runner::HostEngine

use crate::config_file::{PixelCounts, ProcessingConfig};
use crate::engine_runner::EngineBuffers;
use crate::io::FrameShape;
use brightpix_firmware::engine::{FrameError, OutputSink, SubapertureResult};
use brightpix_protocol::{Camera, Config, ConfigError, PixelCount};
use rayon::prelude::*;
use std::sync::Mutex;

/// A batch's slopes, flux and validity, frame-major: entry `f * subapertures
/// + s` is frame `f`, sub-aperture `s` (the configuration's window order).
/// The layout of NumPy arrays of shape `(frames, subapertures, 2)` (int32),
/// `(frames, subapertures)` (int64) and `(frames, subapertures)` (bool).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct BatchResults {
    pub frames: usize,
    pub subapertures: usize,
    /// `[x, y]` in 2^-16 pixel, reference slopes subtracted, 0 when invalid
    /// (SPEC.md §5).
    pub slopes: Vec<[i32; 2]>,
    /// Sum of weights, 1/16 count (reported even when invalid).
    pub flux: Vec<i64>,
    /// Flux above the configuration's minimum.
    pub valid: Vec<bool>,
}

impl BatchResults {
    /// Zeros for `frames` frames of `subapertures` sub-apertures.
    pub fn zeroed(frames: usize, subapertures: usize) -> Self {
        let len = frames * subapertures;
        BatchResults {
            frames,
            subapertures,
            slopes: vec![[0; 2]; len],
            flux: vec![0; len],
            valid: vec![false; len],
        }
    }

    /// The whole batch as output arrays for [`ParallelEngine::process_into`].
    pub fn as_mut(&mut self) -> ResultsMut<'_> {
        ResultsMut {
            slopes: &mut self.slopes,
            flux: &mut self.flux,
            valid: &mut self.valid,
        }
    }

    /// Frame `frame`, sub-aperture `subaperture`, as the engine emits it.
    pub fn get(&self, frame: usize, subaperture: usize) -> SubapertureResult {
        let k = frame * self.subapertures + subaperture;
        SubapertureResult {
            index: subaperture as u16,
            slope_x: self.slopes[k][0],
            slope_y: self.slopes[k][1],
            flux: self.flux[k],
            valid: self.valid[k],
        }
    }

    /// Frame `frame`'s results in sub-aperture order.
    pub fn frame(&self, frame: usize) -> impl Iterator<Item = SubapertureResult> + '_ {
        (0..self.subapertures).map(move |s| self.get(frame, s))
    }
}

/// Caller-owned output arrays (e.g. NumPy buffers), laid out as
/// [`BatchResults`]: each `frames * subapertures` long.
pub struct ResultsMut<'o> {
    pub slopes: &'o mut [[i32; 2]],
    pub flux: &'o mut [i64],
    pub valid: &'o mut [bool],
}

impl<'o> ResultsMut<'o> {
    fn split_at(self, mid: usize) -> (ResultsMut<'o>, ResultsMut<'o>) {
        let (slopes, slopes_tail) = self.slopes.split_at_mut(mid);
        let (flux, flux_tail) = self.flux.split_at_mut(mid);
        let (valid, valid_tail) = self.valid.split_at_mut(mid);
        (
            ResultsMut {
                slopes,
                flux,
                valid,
            },
            ResultsMut {
                slopes: slopes_tail,
                flux: flux_tail,
                valid: valid_tail,
            },
        )
    }

    /// Runs of `len` entries, in parallel.
    fn par_chunks(self, len: usize) -> impl IndexedParallelIterator<Item = ResultsMut<'o>> {
        self.slopes
            .par_chunks_mut(len)
            .zip(self.flux.par_chunks_mut(len))
            .zip(self.valid.par_chunks_mut(len))
            .map(|((slopes, flux), valid)| ResultsMut {
                slopes,
                flux,
                valid,
            })
    }

    #[inline]
    fn set(&mut self, k: usize, result: &SubapertureResult) {
        self.slopes[k] = [result.slope_x, result.slope_y];
        self.flux[k] = result.flux;
        self.valid[k] = result.valid;
    }
}

/// Why a parallel engine could not be made.
#[derive(Debug, thiserror::Error)]
pub enum SetupError {
    #[error("invalid configuration: {0}")]
    Config(#[from] ConfigError),
    #[error("a thread count of 0: give at least 1, or none for all cores")]
    NoThreads,
    #[error("cannot start {threads} worker threads: {message}")]
    ThreadPool { threads: usize, message: String },
}

/// Why a batch was refused. Nothing was processed and no state changed.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum BatchError {
    #[error(
        "frames of {width}x{height} (width x height); the configured camera is {camera_width}x{camera_height}"
    )]
    FrameSize {
        width: usize,
        height: usize,
        camera_width: u16,
        camera_height: u16,
    },
    #[error(
        "{pixels} pixels given for {frames} frame(s) of {width}x{height}, which are {expected}"
    )]
    PixelCount {
        pixels: usize,
        frames: usize,
        width: usize,
        height: usize,
        expected: usize,
    },
    #[error(
        "output arrays of {slopes} slope pairs, {flux} fluxes and {valid} flags; {frames} frame(s) of {subapertures} sub-apertures need {expected} of each"
    )]
    OutputSize {
        slopes: usize,
        flux: usize,
        valid: usize,
        frames: usize,
        subapertures: usize,
        expected: usize,
    },
    #[error("frame {frame}: {error}; no frame of the batch was processed")]
    Pixel { frame: usize, error: FrameError },
}

/// Some of a configuration's windows, as a configuration of their own over
/// the camera rows they span.
struct Part {
    config: ProcessingConfig,
    /// The part's row 0 is this camera row.
    first_row: usize,
    /// Index in the full configuration of each of the part's windows.
    global: Vec<usize>,
}

impl Part {
    /// The windows `members` of `config` (indices, in the part's order).
    fn new(config: &Config<'_>, members: &[usize]) -> Part {
        let windows = config.windows;
        let first_row = members.iter().map(|&k| windows[k].y).min().unwrap_or(0);
        let end_row = members
            .iter()
            .map(|&k| windows[k].last_row() + 1)
            .max()
            .unwrap_or(1);
        let width = config.camera.width as usize;
        let rows = first_row as usize * width..end_row as usize * width;
        let camera = Camera {
            height: end_row - first_row,
            ..config.camera
        };
        let own_windows = members
            .iter()
            .map(|&k| {
                let mut w = windows[k];
                w.y -= first_row;
                w
            })
            .collect();
        let mut part = ProcessingConfig::new(camera, own_windows);
        part.background = config
            .calibration
            .background
            .map(|m| m[rows.clone()].to_vec());
        part.gain = config.calibration.gain.map(|m| m[rows.clone()].to_vec());
        part.threshold = config.calibration.threshold;
        part.rule = config.selection.rule;
        part.pixels = match config.selection.count {
            PixelCount::All(n) => PixelCounts::All(n),
            PixelCount::PerSubaperture(list) => {
                PixelCounts::PerSubaperture(members.iter().map(|&k| list[k]).collect())
            }
        };
        part.level_filter = config.selection.level_filter;
        part.reference_slopes = config
            .centroid
            .reference_slopes
            .map(|r| members.iter().map(|&k| r[k]).collect());
        part.min_flux = config.centroid.min_flux;
        Part {
            config: part,
            first_row: first_row as usize,
            global: members.to_vec(),
        }
    }

    /// The part's rows of a full camera frame.
    fn rows<'f>(&self, frame: &'f [u16]) -> &'f [u16] {
        let width = self.config.camera.width as usize;
        let height = self.config.camera.height as usize;
        &frame[self.first_row * width..(self.first_row + height) * width]
    }

    fn buffers(&self) -> EngineBuffers {
        EngineBuffers::for_config(&self.config.view())
    }

    /// Runs whole camera frames `pixels` through an engine on `buffers`
    /// (resuming its level-filter state), writing frame `f`'s results at
    /// `f * per_frame` in `out`: by full-configuration index if
    /// `by_global`, else by the part's own.
    fn run(
        &self,
        buffers: &mut EngineBuffers,
        pixels: &[u16],
        frame_pixels: usize,
        mut out: ResultsMut<'_>,
        per_frame: usize,
        by_global: bool,
    ) -> Result<(), (usize, FrameError)> {
        let mut engine = buffers
            .resume(self.config.view())
            .expect("parts are validated and their buffers sized when the parallel engine is made");
        let global = by_global.then_some(self.global.as_slice());
        for (f, frame) in pixels.chunks_exact(frame_pixels).enumerate() {
            let (head, tail) = out.split_at(per_frame);
            let mut sink = FrameSink { out: head, global };
            engine.push(self.rows(frame), &mut sink).map_err(|e| {
                let FrameError::PixelOutOfRange { row, column, value } = e;
                let row = row + self.first_row as u16;
                (f, FrameError::PixelOutOfRange { row, column, value })
            })?;
            out = tail;
        }
        Ok(())
    }
}

/// Writes one frame's results where they belong.
struct FrameSink<'o, 'g> {
    out: ResultsMut<'o>,
    global: Option<&'g [usize]>,
}

impl OutputSink for FrameSink<'_, '_> {
    #[inline]
    fn subaperture(&mut self, result: SubapertureResult) {
        let local = result.index as usize;
        let k = self.global.map_or(local, |g| g[local]);
        let result = SubapertureResult {
            index: k as u16,
            ..result
        };
        self.out.set(k, &result);
    }
}

/// A band of sub-apertures with its engine memory (level-filter state) and
/// room for a batch of its results.
struct Band {
    part: Part,
    buffers: EngineBuffers,
    results: BatchResults,
}

/// Where the work runs.
enum Workers {
    /// On the caller's thread.
    Inline,
    /// Rayon's global pool (all cores unless `RAYON_NUM_THREADS` says otherwise).
    Global,
    Pool(rayon::ThreadPool),
}

impl Workers {
    fn threads(&self) -> usize {
        match self {
            Workers::Inline => 1,
            Workers::Global => rayon::current_num_threads(),
            Workers::Pool(pool) => pool.current_num_threads(),
        }
    }

    fn run<R: Send>(&self, work: impl FnOnce() -> R + Send) -> R {
        match self {
            Workers::Inline | Workers::Global => work(),
            Workers::Pool(pool) => pool.install(work),
        }
    }
}

/// The streaming engine on all cores for one configuration: batch after
/// batch of frames, with the level-filter state (SPEC.md §4) carried from
/// one batch to the next, as a [`HostEngine`](crate::engine_runner::HostEngine)
/// would carry it from frame to frame. Owns a copy of what it needs of the
/// configuration.
pub struct ParallelEngine {
    camera: Camera,
    subapertures: usize,
    level_filter: bool,
    /// All windows, in configuration order, over the rows they span.
    whole: Part,
    /// Engine memory for `whole`, one per worker thread, made when a batch
    /// is first split by frames and kept from run to run and batch to
    /// batch: a run then starts from the seeds its thread's last run left
    /// (seeds set only where selection starts, never the results; without
    /// the level filter nothing else carries over) instead of cold, and
    /// allocates nothing.
    worker_memory: Vec<Mutex<Option<EngineBuffers>>>,
    bands: Vec<Band>,
    workers: Workers,
}

impl ParallelEngine {
    /// An engine for `config` on `threads` threads (`None`: all cores;
    /// `Some(1)`: the caller's thread only).
    pub fn new(config: &Config<'_>, threads: Option<usize>) -> Result<Self, SetupError> {
        config.validate()?;
        let workers = match threads {
            None => Workers::Global,
            Some(0) => return Err(SetupError::NoThreads),
            Some(1) => Workers::Inline,
            Some(n) => Workers::Pool(
                rayon::ThreadPoolBuilder::new()
                    .num_threads(n)
                    .thread_name(|k| format!("brightpix-{k}"))
                    .build()
                    .map_err(|e| SetupError::ThreadPool {
                        threads: n,
                        message: e.to_string(),
                    })?,
            ),
        };
        let count = config.windows.len();
        let all: Vec<usize> = (0..count).collect();
        let whole = Part::new(config, &all);
        // Check the part configurations (and that engine memory fits them) now,
        // so that processing cannot fail on them.
        whole.buffers().resume(whole.config.view())?;
        let bands = band_members(config, workers.threads())
            .iter()
            .map(|members| {
                let part = Part::new(config, members);
                let mut buffers = part.buffers();
                // `start`, not `resume`: fresh level-filter state.
                buffers.start(part.config.view())?;
                Ok(Band {
                    part,
                    buffers,
                    results: BatchResults::default(),
                })
            })
            .collect::<Result<Vec<_>, ConfigError>>()?;
        Ok(ParallelEngine {
            camera: config.camera,
            subapertures: count,
            level_filter: config.selection.level_filter.is_some(),
            whole,
            worker_memory: (0..workers.threads()).map(|_| Mutex::new(None)).collect(),
            bands,
            workers,
        })
    }

    /// Threads the work runs on.
    pub fn threads(&self) -> usize {
        self.workers.threads()
    }

    /// Sub-aperture bands a level-filtered batch is split into.
    pub fn bands(&self) -> usize {
        self.bands.len()
    }

    pub fn camera(&self) -> Camera {
        self.camera
    }

    pub fn subapertures(&self) -> usize {
        self.subapertures
    }

    /// Forgets the filtered levels (SPEC.md §4), as a newly applied
    /// configuration does.
    pub fn reset_level_filters(&mut self) {
        for band in &mut self.bands {
            band.buffers.reset_level_filters();
        }
    }

    /// Processes `shape.frames` frames of `pixels` (raw, row-major, frame
    /// after frame) into new result arrays.
    pub fn process(
        &mut self,
        pixels: &[u16],
        shape: FrameShape,
    ) -> Result<BatchResults, BatchError> {
        let mut results = BatchResults::zeroed(shape.frames, self.subapertures);
        self.process_into(pixels, shape, results.as_mut())?;
        Ok(results)
    }

    /// As [`process`](Self::process), into caller-owned arrays of
    /// `shape.frames * subapertures` entries each. On an error nothing is
    /// written.
    pub fn process_into(
        &mut self,
        pixels: &[u16],
        shape: FrameShape,
        out: ResultsMut<'_>,
    ) -> Result<(), BatchError> {
        self.check_batch(pixels, shape, &out)?;
        if shape.frames == 0 {
            return Ok(());
        }
        let frame_pixels = shape.pixels_per_frame();
        let per_frame = self.subapertures;
        let threads = self.threads();
        let outcome = if threads == 1 || self.bands.len() == 1 {
            // One band holds every window: its results go straight out.
            let band = &mut self.bands[0];
            band.part.run(
                &mut band.buffers,
                pixels,
                frame_pixels,
                out,
                per_frame,
                true,
            )
        } else if !self.level_filter && shape.frames >= threads {
            let (whole, memory) = (&self.whole, &self.worker_memory);
            // A few runs per thread, so a thread slowed by others catches up,
            // of at least about a million pixels (each run starts an engine).
            let run = shape
                .frames
                .div_ceil(4 * threads)
                .max((1 << 20) / frame_pixels.max(1))
                .min(shape.frames.div_ceil(threads));
            self.workers.run(|| {
                pixels
                    .par_chunks(run * frame_pixels)
                    .zip(out.par_chunks(run * per_frame))
                    .enumerate()
                    .try_for_each(|(k, (pixels, out))| {
                        // Each worker locks only its own memory: never contended.
                        let worker = rayon::current_thread_index().unwrap_or(0) % memory.len();
                        let mut slot = memory[worker].lock().unwrap_or_else(|e| e.into_inner());
                        let buffers = slot.get_or_insert_with(|| whole.buffers());
                        whole
                            .run(buffers, pixels, frame_pixels, out, per_frame, false)
                            .map_err(|(f, e)| (k * run + f, e))
                    })
            })
        } else {
            self.run_bands(pixels, shape, out)
        };
        outcome.map_err(|(frame, error)| BatchError::Pixel { frame, error })
    }

    /// Each band through all frames, in parallel; then its results scattered
    /// to their sub-apertures.
    fn run_bands(
        &mut self,
        pixels: &[u16],
        shape: FrameShape,
        out: ResultsMut<'_>,
    ) -> Result<(), (usize, FrameError)> {
        let frame_pixels = shape.pixels_per_frame();
        let bands = &mut self.bands;
        self.workers.run(|| {
            bands.par_iter_mut().try_for_each(|band| {
                let count = band.part.global.len();
                if band.results.frames != shape.frames {
                    band.results = BatchResults::zeroed(shape.frames, count);
                }
                let Band {
                    part,
                    buffers,
                    results,
                } = band;
                part.run(
                    buffers,
                    pixels,
                    frame_pixels,
                    results.as_mut(),
                    count,
                    false,
                )
            })
        })?;
        let bands = &self.bands;
        self.workers.run(|| {
            out.par_chunks(self.subapertures)
                .enumerate()
                .for_each(|(f, frame)| {
                    for band in bands {
                        let count = band.part.global.len();
                        for (local, &k) in band.part.global.iter().enumerate() {
                            let at = f * count + local;
                            frame.slopes[k] = band.results.slopes[at];
                            frame.flux[k] = band.results.flux[at];
                            frame.valid[k] = band.results.valid[at];
                        }
                    }
                })
        });
        Ok(())
    }

    /// Shapes, then every pixel against the bit depth.
    fn check_batch(
        &self,
        pixels: &[u16],
        shape: FrameShape,
        out: &ResultsMut<'_>,
    ) -> Result<(), BatchError> {
        let camera = self.camera;
        if shape.width != camera.width as usize || shape.height != camera.height as usize {
            return Err(BatchError::FrameSize {
                width: shape.width,
                height: shape.height,
                camera_width: camera.width,
                camera_height: camera.height,
            });
        }
        let frame_pixels = shape.pixels_per_frame();
        let expected = shape.frames * frame_pixels;
        if pixels.len() != expected {
            return Err(BatchError::PixelCount {
                pixels: pixels.len(),
                frames: shape.frames,
                width: shape.width,
                height: shape.height,
                expected,
            });
        }
        let entries = shape.frames * self.subapertures;
        if [out.slopes.len(), out.flux.len(), out.valid.len()] != [entries; 3] {
            return Err(BatchError::OutputSize {
                slopes: out.slopes.len(),
                flux: out.flux.len(),
                valid: out.valid.len(),
                frames: shape.frames,
                subapertures: self.subapertures,
                expected: entries,
            });
        }
        let max = camera.max_raw();
        if max == u16::MAX || frame_pixels == 0 {
            return Ok(());
        }
        let bad_frame = self.workers.run(|| {
            pixels
                .par_chunks(frame_pixels)
                .position_first(|frame| frame.iter().fold(0, |m, &v| m.max(v)) > max)
        });
        match bad_frame {
            None => Ok(()),
            Some(frame) => {
                let pixels = &pixels[frame * frame_pixels..][..frame_pixels];
                let at = pixels.iter().position(|&v| v > max).unwrap_or(0);
                Err(BatchError::Pixel {
                    frame,
                    error: FrameError::PixelOutOfRange {
                        row: (at / shape.width) as u16,
                        column: (at % shape.width) as u16,
                        value: pixels[at],
                    },
                })
            }
        }
    }
}

/// The windows of `config` in `bands` bands: raster order of their first
/// pixel (first row, then column), cut where the running pixel count passes
/// each `k / bands` of the total. At most one band per window.
fn band_members(config: &Config<'_>, bands: usize) -> Vec<Vec<usize>> {
    let windows = config.windows;
    let mut order: Vec<usize> = (0..windows.len()).collect();
    order.sort_by_key(|&k| (windows[k].y, windows[k].x));
    let bands = bands.clamp(1, windows.len().max(1));
    let total: usize = windows.iter().map(|w| w.pixel_count()).sum();
    let mut out = vec![Vec::new(); bands];
    let mut seen = 0;
    for (position, &k) in order.iter().enumerate() {
        // The band of this window's middle pixel, but leave at least one
        // window for each band still to come.
        let middle = seen + windows[k].pixel_count() / 2;
        let by_pixels = (middle * bands / total.max(1)).min(bands - 1);
        let left = windows.len() - position;
        let band = by_pixels.max(bands.saturating_sub(left));
        out[band].push(k);
        seen += windows[k].pixel_count();
    }
    out.retain(|b| !b.is_empty());
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use brightpix_protocol::RegularGrid;

    fn grid(columns: u16, rows: u16) -> ProcessingConfig {
        let camera = Camera {
            width: columns * 4,
            height: rows * 4,
            bit_depth: 12,
        };
        let grid = RegularGrid {
            x: 0,
            y: 0,
            columns,
            rows,
            width: 4,
            height: 4,
            pitch_x: 4,
            pitch_y: 4,
        };
        ProcessingConfig::from_grid(camera, grid, &[])
    }

    #[test]
    fn bands_cover_every_window_once_in_raster_order() {
        for (columns, rows, bands) in [(7, 7, 2), (7, 7, 3), (1, 1, 4), (3, 1, 8), (15, 15, 2)] {
            let config = grid(columns, rows);
            let members = band_members(&config.view(), bands);
            let flat: Vec<usize> = members.concat();
            assert_eq!(flat, (0..config.windows.len()).collect::<Vec<_>>());
            assert_eq!(members.len(), bands.min(config.windows.len()));
            let sizes: Vec<usize> = members.iter().map(Vec::len).collect();
            let (least, most) = (sizes.iter().min().unwrap(), sizes.iter().max().unwrap());
            assert!(most - least <= 1, "{sizes:?}");
        }
    }

    #[test]
    fn refuses_bad_batches_before_any_work() {
        let config = grid(2, 2);
        let mut engine = ParallelEngine::new(&config.view(), Some(2)).unwrap();
        let shape = FrameShape {
            frames: 2,
            height: 8,
            width: 8,
        };
        let mut pixels = vec![7u16; 128];
        assert!(matches!(
            engine.process(&pixels[1..], shape),
            Err(BatchError::PixelCount { expected: 128, .. })
        ));
        let wrong = FrameShape {
            width: 16,
            height: 4,
            ..shape
        };
        assert!(matches!(
            engine.process(&pixels, wrong),
            Err(BatchError::FrameSize { width: 16, .. })
        ));
        let mut small = BatchResults::zeroed(1, 4);
        assert!(matches!(
            engine.process_into(&pixels, shape, small.as_mut()),
            Err(BatchError::OutputSize { expected: 8, .. })
        ));
        pixels[64 + 8 * 3 + 5] = 4096;
        assert_eq!(
            engine.process(&pixels, shape),
            Err(BatchError::Pixel {
                frame: 1,
                error: FrameError::PixelOutOfRange {
                    row: 3,
                    column: 5,
                    value: 4096
                }
            })
        );
        assert!(matches!(
            ParallelEngine::new(&config.view(), Some(0)),
            Err(SetupError::NoThreads)
        ));
    }
}
