//! One workload measured for the device loop's bench request (PROTOCOL.md
//! §14), in the memory the device lends ([`BenchMemory`]: its engine
//! memory, the staging slot's windows, background map and gain map, the
//! last holding the frames) and the board's [`BenchBuffers`].
//!
//! The same [`measure`] as the QEMU bench, on the same generated frames:
//! the engine one camera row per push, then the floor (the paper's sort is
//! left out; the report carries the engine and the floor).

use core::cell::Cell;

use brightpix_firmware::device::{BenchMemory, BenchRunner};
use brightpix_firmware::engine::calibrate::WindowBounds;
use brightpix_firmware::engine::SubapertureResult;
use brightpix_protocol::wire::{
    BenchFigures, BenchLimit, BenchReport, BenchResult, CountUnit, FloorCheck, Spread,
};

use crate::workloads::{
    measure, Buffers, FrameCounts, Workload, ALL, CAMERA_RUN_PIXELS, CAMERA_RUN_WORDS,
    ENGINE_REFUSED,
};
use crate::Counter;

/// The widest grid row a board's floor holds (its stack is small): every
/// workload but the ELT-like grid's 80 windows across.
pub const BOARD_ACROSS: usize = 16;

const NO_RESULT: SubapertureResult = SubapertureResult {
    index: 0,
    slope_x: 0,
    slope_y: 0,
    flux: 0,
    valid: false,
};

const NO_COUNTS: FrameCounts = FrameCounts {
    engine: 0.0,
    engine_last_row: 0.0,
    floor: 0.0,
    floor_last_row: 0.0,
};

/// A counter that also keeps each measured frame's counts: [`measure`]
/// calls it, every frame, with `between_frames` and then, in this order,
/// the engine's pushes before those that carry the frame's last row, those
/// pushes, the floor's rows before the last, the floor's last row, and the
/// rest (the other floors), which it leaves out. Wrapping the counter keeps
/// [`measure`]'s timed code as the QEMU tables have it.
pub struct Recorder<'a, C> {
    inner: &'a C,
    samples: &'a [Cell<FrameCounts>],
    /// Frames started.
    frame: Cell<usize>,
    /// Counts in this frame so far.
    call: Cell<usize>,
}

impl<'a, C: Counter> Recorder<'a, C> {
    /// Each frame's counts into `samples` (as many as it holds).
    pub fn new(inner: &'a C, samples: &'a mut [FrameCounts]) -> Self {
        for s in samples.iter_mut() {
            *s = NO_COUNTS;
        }
        Recorder {
            inner,
            samples: Cell::from_mut(samples).as_slice_of_cells(),
            frame: Cell::new(0),
            call: Cell::new(0),
        }
    }

    #[inline(never)]
    fn record(&self, count: f64) {
        let k = self.call.get();
        self.call.set(k + 1);
        let Some(slot) = self
            .frame
            .get()
            .checked_sub(1)
            .and_then(|f| self.samples.get(f))
        else {
            return;
        };
        let mut s = slot.get();
        match k {
            0 => s.engine += count,
            1 => {
                s.engine += count;
                s.engine_last_row += count;
            }
            2 => s.floor += count,
            3 => {
                s.floor += count;
                s.floor_last_row += count;
            }
            _ => {}
        }
        slot.set(s);
    }
}

impl<C: Counter> Counter for Recorder<'_, C> {
    #[inline(always)]
    fn count<R>(&self, f: impl FnOnce() -> R) -> (f64, R) {
        let (count, r) = self.inner.count(f);
        self.record(count);
        (count, r)
    }

    #[inline(always)]
    fn between_frames(&self) {
        self.inner.between_frames();
        self.frame.set(self.frame.get() + 1);
        self.call.set(0);
    }
}

/// The bench's own per-window buffers and per-frame counts, for up to `W`
/// windows and `F` measured frames; const-constructible, for a `static`
/// in whichever memory the board has room in.
pub struct BenchBuffers<const W: usize, const F: usize> {
    levels: [i32; W],
    bounds: [WindowBounds; W],
    engine_results: [SubapertureResult; W],
    floor_results: [SubapertureResult; W],
    samples: [FrameCounts; F],
    /// The camera source's run buffers (`Workload::camera`).
    camera_words: [u32; CAMERA_RUN_WORDS],
    camera_pixels: [u16; CAMERA_RUN_PIXELS],
}

impl<const W: usize, const F: usize> BenchBuffers<W, F> {
    pub const fn new() -> Self {
        BenchBuffers {
            levels: [0; W],
            bounds: [WindowBounds::NONE; W],
            engine_results: [NO_RESULT; W],
            floor_results: [NO_RESULT; W],
            samples: [NO_COUNTS; F],
            camera_words: [0; CAMERA_RUN_WORDS],
            camera_pixels: [0; CAMERA_RUN_PIXELS],
        }
    }
}

impl<const W: usize, const F: usize> Default for BenchBuffers<W, F> {
    fn default() -> Self {
        Self::new()
    }
}

/// A board's counter, as the bench request reports it.
pub trait BoardCounter: Counter {
    /// Made ready for a workload (e.g. calibrated); what it counts and the
    /// core clock (Hz) if cycles.
    fn start(&mut self) -> (CountUnit, Option<u32>);
}

/// A board's bench mode: [`BenchRunner`] over [`workloads::ALL`](ALL).
pub struct BoardBench<'b, C, const W: usize, const F: usize> {
    counter: C,
    buffers: &'b mut BenchBuffers<W, F>,
}

impl<'b, C: BoardCounter, const W: usize, const F: usize> BoardBench<'b, C, W, F> {
    pub fn new(counter: C, buffers: &'b mut BenchBuffers<W, F>) -> Self {
        BoardBench { counter, buffers }
    }
}

impl<C: BoardCounter, const W: usize, const F: usize> BenchRunner for BoardBench<'_, C, W, F> {
    fn workloads(&self) -> usize {
        ALL.len()
    }

    fn name(&self, index: usize) -> &'static str {
        ALL.get(index).map_or("", |w| w.name)
    }

    fn max_frames(&self) -> u32 {
        F as u32
    }

    fn run(&mut self, index: usize, frames: u32, memory: BenchMemory<'_>) -> BenchReport<'static> {
        let base = ALL[index];
        let w = Workload {
            frames: if frames == 0 {
                base.frames
            } else {
                frames as usize
            },
            sort: false,
            ..base
        };
        let (unit, clock_hz) = self.counter.start();
        let grid = w.grid;
        let pixels = grid.pixels();
        let report = |result| BenchReport {
            workload: w.name,
            unit,
            clock_hz,
            pixels: pixels as u32,
            frames: w.frames as u32,
            result,
        };
        let BenchMemory {
            engine,
            windows,
            background,
            gain,
        } = memory;
        // The frames in the gain map, from its first word (the row kernels
        // read pixels two to a word).
        let skip = (gain.as_ptr() as usize & 3) / 2;
        let frame = gain.get_mut(skip..).unwrap_or_default();
        if frame.len() < pixels || (w.background && background.len() < pixels) {
            return report(BenchResult::DoesNotFit {
                limit: BenchLimit::Pixels,
            });
        }
        if grid.windows() > W.min(windows.len()) || grid.across > BOARD_ACROSS || w.frames > F {
            return report(BenchResult::DoesNotFit {
                limit: BenchLimit::Windows,
            });
        }
        let b = &mut *self.buffers;
        let mut buffers = Buffers {
            frame: &mut frame[..pixels],
            background,
            windows,
            levels: &mut b.levels,
            bounds: &mut b.bounds,
            engine_results: &mut b.engine_results,
            floor_results: &mut b.floor_results,
            camera_words: &mut b.camera_words,
            camera_pixels: &mut b.camera_pixels,
        };
        let recorder = Recorder::new(&self.counter, &mut b.samples[..w.frames]);
        let measured = measure::<_, BOARD_ACROSS>(&w, &recorder, &mut buffers, engine);
        match measured {
            Ok(m) => {
                let samples = &b.samples[..w.frames];
                // One array for the four (the board's stack is small).
                let mut values = [0u64; F];
                let mut spread = |f: fn(&FrameCounts) -> f64| {
                    for (v, s) in values.iter_mut().zip(samples) {
                        *v = round(f(s));
                    }
                    Spread::of(&mut values[..samples.len()])
                };
                report(BenchResult::Measured(BenchFigures {
                    engine_total: round(m.engine),
                    engine_frame: spread(|s| s.engine),
                    engine_last_row: spread(|s| s.engine_last_row),
                    floor_total: round(m.floor),
                    floor_frame: spread(|s| s.floor),
                    floor_last_row: spread(|s| s.floor_last_row),
                    floor_check: if w.floor_comparable() {
                        FloorCheck::Equal
                    } else {
                        FloorCheck::NotComparable
                    },
                }))
            }
            Err(e) if e.what == ENGINE_REFUSED => report(BenchResult::DoesNotFit {
                limit: BenchLimit::EngineMemory,
            }),
            Err(e) => report(BenchResult::SlopesDiffer {
                window: e.index as u32,
            }),
        }
    }
}

/// A count to the nearest whole one (counts are never negative).
fn round(v: f64) -> u64 {
    if v > 0.0 {
        (v + 0.5) as u64
    } else {
        0
    }
}
